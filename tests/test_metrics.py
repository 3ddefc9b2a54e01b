"""Report metrics on clouds with known answers."""

import math

import numpy as np
import pytest
import torch

from lerobot_taxdpd.maths import metrics
from lerobot_taxdpd.maths.geometry import make_transform, rotation_about_z, transform_points


def test_translation_rotation_and_rmse_of_a_known_motion():
    cloud = np.random.default_rng(0).normal(size=(200, 3))
    motion = make_transform(
        rotation_about_z(torch.tensor(math.radians(7.0), dtype=torch.float64)),
        torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64),
    )
    moved = transform_points(motion.numpy(), cloud)
    assert metrics.rotation_error_deg(moved, cloud) == pytest.approx(7.0, abs=1e-6)
    shifted = cloud + np.array([0.003, 0.004, 0.0])
    assert metrics.translation_error(shifted, cloud) == pytest.approx(0.005)
    assert metrics.point_rmse(shifted, cloud) == pytest.approx(0.005)


def test_winner_take_all_picks_the_best_sample():
    target = np.zeros((1, 10, 3))
    samples = np.stack([np.full((10, 3), v) for v in (0.3, 0.01, -0.2)])[None]
    assert metrics.winner_take_all_rmse(samples, target)[0] == pytest.approx(0.01 * math.sqrt(3))


def test_each_sample_is_scored_against_the_valid_goal_it_went_for():
    cloud = np.random.default_rng(1).normal(size=(50, 3))
    turn = make_transform(
        rotation_about_z(torch.tensor(math.radians(5.0), dtype=torch.float64)), torch.zeros(3, dtype=torch.float64)
    )
    goals = np.stack([cloud, cloud + [2.0, 0.0, 0.0]])  # two valid goals, 2 m apart
    samples = np.stack([goals[1] + [0.0, 0.01, 0.0], transform_points(turn.numpy(), goals[0])])
    scores = metrics.score_against_valid_goals(samples, goals)
    assert scores.nearest.tolist() == [1, 0]
    assert scores.rmse.shape == (2, 2)
    assert scores.translation_error == pytest.approx([0.01, np.linalg.norm(samples[1].mean(0) - cloud.mean(0))])
    assert scores.rotation_error_deg == pytest.approx([0.0, 5.0], abs=1e-4)
    assert scores.nearest_rmse[0] == pytest.approx(0.01)


def test_coverage_and_precision_of_multimodal_samples():
    goals = np.stack([np.zeros((5, 3)), np.ones((5, 3))])  # two valid goals
    samples = np.stack([np.zeros((5, 3)), np.zeros((5, 3)) + 0.001, np.full((5, 3), 5.0)])
    result = metrics.coverage_precision(samples, goals, threshold=0.01)
    assert result["coverage"] == 0.5  # the second goal is never reached
    assert result["precision"] == pytest.approx(2 / 3)  # the far sample matches no goal


def test_wilson_interval_is_sane_at_the_edges():
    low, high = metrics.wilson_interval(100, 100)
    assert high == pytest.approx(1.0) and 0.95 < low < 0.97
    low, high = metrics.wilson_interval(0, 20)
    assert low == 0.0 and 0.15 < high < 0.18
    summary = metrics.success_summary(78, 100)
    assert summary["ci95_low"] < 0.78 < summary["ci95_high"]


def test_paired_difference_separates_a_small_shift_hidden_in_a_large_spread():
    rng = np.random.default_rng(0)
    scenes = rng.uniform(0, 100, 100)  # per-scene difficulty, far larger than the effect
    mean, low, high = metrics.paired_difference(scenes + 2.0 + rng.normal(0, 0.5, 100), scenes)
    assert 1.8 < mean < 2.2 and 0 < low < mean < high < 2.5
    assert metrics.paired_difference(scenes, scenes) == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="same non-zero length"):
        metrics.paired_difference(scenes, scenes[:-1])
