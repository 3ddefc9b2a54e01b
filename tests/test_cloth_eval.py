"""`eval --task cloth_hang`: valid goals, goal-predictor metrics, gc_dp3 rollouts, PNGs, in parallel workers.

The checkpoints are untrained (saved the way lerobot-train saves them): this checks the pipeline and its
report, not the policies' skill.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_taxdpd import GcDp3Config, TaxDPDConfig, load_goal_predictor, make_gc_dp3_pre_post_processors
from lerobot_taxdpd.data.schema import ACTION_KEY, GOAL_CLOUD_KEY, OBJECT_KEY, SCENE_KEY, STATE_KEY
from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy
from lerobot_taxdpd.policies.taxdpd.modeling_taxdpd import TaxDPDPolicy
from lerobot_taxdpd.sim.cli import main
from lerobot_taxdpd.sim.cloth.evaluation import load_gc_dp3

CLOUD = PolicyFeature(FeatureType.STATE, (512, 3))


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory):
    root = tmp_path_factory.mktemp("checkpoints")
    inputs = {
        OBJECT_KEY: CLOUD,
        SCENE_KEY: CLOUD,
        GOAL_CLOUD_KEY: CLOUD,
        STATE_KEY: PolicyFeature(FeatureType.STATE, (12,)),
    }
    config = GcDp3Config(
        input_features=inputs,
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, (6,))},
        down_dims=(16, 32),
        point_encoder_dims=(16, 16),
        point_feature_dim=16,
        state_encoder_dims=(16, 16),
        diffusion_step_embed_dim=16,
        num_inference_steps=2,
        points_per_cloud=64,
        use_ema=True,
        cloud_center=[0.0, -1.0, 4.0],  # the isotropic frame a trained checkpoint carries
        cloud_scale=5.0,
        device="cpu",
    )
    torch.manual_seed(0)
    policy = GcDp3Policy(config)
    with torch.no_grad():  # EMA weights that differ from the trained ones, as after training
        for parameter in policy.ema_model.parameters():
            parameter.add_(0.01 * torch.randn_like(parameter))
    stats = {
        STATE_KEY: {
            "min": torch.tensor([-4.0, -4.0, 4.0] * 2 + [-2.0] * 6),
            "max": torch.tensor([4.0, 2.0, 8.0] * 2 + [2.0] * 6),
        },
        ACTION_KEY: {"min": torch.full((6,), -0.08), "max": torch.full((6,), 0.08)},
    }
    gc_dp3 = root / "gc_dp3"
    policy.save_pretrained(gc_dp3)
    for pipeline in make_gc_dp3_pre_post_processors(config, dataset_stats=stats):
        pipeline.save_pretrained(gc_dp3)
    goal_config = TaxDPDConfig(
        input_features={OBJECT_KEY: CLOUD, SCENE_KEY: CLOUD},
        output_features={ACTION_KEY: PolicyFeature(FeatureType.ACTION, (512, 3))},
        num_scene_points=512,
        hidden_dim=16,
        num_blocks=1,
        num_heads=2,
        max_neighbors=16,
        num_inference_steps=2,
        point_scale=1.0,
        device="cpu",
    )
    taxdpd = root / "taxdpd"
    TaxDPDPolicy(goal_config).save_pretrained(taxdpd)
    return gc_dp3, taxdpd


def test_eval_reports_success_goal_metrics_and_plots(checkpoints, tmp_path, capsys):
    gc_dp3, taxdpd = checkpoints
    out = tmp_path / "eval"
    argv = ["eval", "--task", "cloth_hang", "--trials", "2", "--seed", "8", "--workers", "2", "--figures", "1"]
    argv += ["--policy.path", str(gc_dp3), "--goal-policy.path", str(taxdpd), "--ground-truth-goals"]
    argv += ["--compare-selections", "first"]
    assert main([*argv, "--num-samples", "3", "--output", str(out), "--ship", str(tmp_path / "shipped")]) == 0
    summary = json.loads((out / "cloth_hang_eval.json").read_text())
    printed = capsys.readouterr().out.splitlines()  # one summary line, as the rigid tasks print, not the JSON
    lines = [line for line in printed if line.startswith("cloth_hang: ")]
    assert len(lines) == 1 and lines[0].startswith("cloth_hang: success with predicted goals ")
    assert "with predicted goals chosen by first " in lines[0]
    assert "with ground-truth goals" in lines[0] and lines[0].endswith(f"report: {out / 'cloth_hang_eval.json'}")
    assert not [line for line in printed if line.lstrip().startswith(("{", "}", '"'))]
    assert summary["trials"] == 2 and summary["workers"] == 2 and summary["config"]["split"] == "test"
    assert summary["machine"]["cpu_count"] >= 1 and summary["machine"]["torch_threads"] >= 1
    for name in ("ground_truth_goal", "predicted_goal"):
        rate = summary[name]
        assert rate["trials"] == 2 and 0.0 <= rate["ci95_low"] <= rate["success_rate"] <= rate["ci95_high"] <= 1.0
        assert rate["median_seconds_per_episode"] > 0 and 0.0 <= rate["hole_at_a_peg_before_release"] <= 1.0
    trials = summary["per_trial"]
    assert [t["seed"] for t in trials] == [8, 9]
    for trial in trials:
        assert len(trial["sample_goal_rmse"]) == 3 and 0 <= trial["executed_sample"] < 3
        assert trial["holes"] == 1
        assert sorted(trial["valid_goals"]) == [[0, 0], [0, 1]], "the expert hangs the one hole on either hanger"
        assert trial["ground_truth_pair"] == trial["valid_goals"][0]
    assert summary["config"]["goal_selection"] == "consensus"  # cloth's default: measured better than the first
    valid = [t["sample_goal_rmse"][t["executed_sample"]] < 0.5 for t in trials]
    assert summary["executed_goal_valid"] == np.mean(valid)
    # The first sample, executed on the same samples beside the consensus one; a sample both rules choose is
    # hung once and counted for both.
    first = summary["compared_selections"]["first"]
    assert first["trials"] == 2 and sum(first["paired"].values()) == 2 and set(first["paired"]) == {
        "both", "only_consensus", "only_first", "neither"
    }
    for trial in trials:
        compared = trial["compared_selections"]["first"]
        assert compared["executed_sample"] == 0
        if trial["executed_sample"] == 0:
            assert compared["predicted_goal"] == trial["predicted_goal"]
    metrics = summary["goal_metrics"]
    assert 0.0 < metrics["precision_rmse"] and 0.0 < metrics["coverage_rmse"]
    assert 0.0 <= metrics["coverage"] <= 1.0 and 0.0 <= metrics["precision"] <= 1.0
    # The trivial baseline beside the goal metrics: one copied start cloth, so coverage RMSE >= precision RMSE.
    copied = summary["copy_start_goal_metrics"]
    assert copied["coverage_rmse"] >= copied["precision_rmse"] > 0.0
    turns = summary["equivariance_deg"]
    assert turns["trials"] == 2 and turns["ideal"] == {"scene_yaw": 20.0, "object_yaw": 0.0, "object_tilt": 0.0}
    assert all(abs(turns[name]) <= 180.0 for name in ("scene_yaw", "object_yaw", "object_tilt"))
    figures = sorted((out / "figures").glob("*.png"))
    assert [p.name for p in figures] == ["test_0008.png"]
    assert figures[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert summary["median_seconds_per_trial"] > 0
    shipped = load_goal_predictor(tmp_path / "shipped" / "cloth_hang")
    assert shipped.metrics["task"] == "cloth_hang" and shipped.metrics["success"] == {
        k: summary["predicted_goal"][k] for k in ("success_rate", "ci95_low", "ci95_high", "trials")
    }
    assert shipped.metrics["coverage_rmse"] == metrics["coverage_rmse"]
    assert shipped.metrics["coverage@3"] == metrics["coverage"]  # named as the rigid tasks name it
    assert shipped.metrics["equivariance_deg"] == turns and shipped.metrics["copy_start_goal_metrics"] == copied
    assert shipped.metrics["executed_goal_valid"] == summary["executed_goal_valid"]
    assert shipped.metrics["goal_selection"] == "consensus" and "its consensus sample" in shipped.metrics["evaluation"]
    card = (tmp_path / "shipped" / "cloth_hang" / "README.md").read_text()
    assert "- Orientation: turning the scene by 20 deg" in card and "the start cloth moved to the goal's" in card
    # The executor ships beside it: the EMA weights it acts with, as its only weights, with the same results.
    trained = GcDp3Policy.from_pretrained(gc_dp3)
    executor, _, _ = load_gc_dp3(str(tmp_path / "shipped" / "cloth_hang" / "executor"))
    assert not executor.config.use_ema and not hasattr(executor, "ema_model")
    for name, value in trained.ema_model.state_dict().items():
        torch.testing.assert_close(executor.model.state_dict()[name], value, atol=1e-3, rtol=1e-3)
    assert executor.metrics["success"] == shipped.metrics["success"]
    assert executor.metrics["success_with_ground_truth_goals"]["trials"] == 2
    card = (tmp_path / "shipped" / "cloth_hang" / "executor" / "README.md").read_text()
    assert "## Measured" in card and "success with ground-truth goals" in card


def test_eval_explains_what_is_missing(checkpoints, tmp_path, capsys):
    gc_dp3, _ = checkpoints
    base = ["eval", "--task", "cloth_hang", "--trials", "1", "--output", str(tmp_path)]
    for argv, message in [
        ([*base, "--policy.path", str(gc_dp3)], "give --goal-policy.path"),
        ([*base, "--policy.path", str(tmp_path / "nowhere"), "--ground-truth-goals"], "--policy.path: "),
        ([*base[:-4], "--trials", "0", "--policy.path", str(gc_dp3), "--ground-truth-goals"], "trials"),
        ([*base, "--predictor", "oracle"], "--predictor: only applies to a rigid task"),
        ([*base, "--goal-policy.path", "cloth_hang", "--compare-selections", "first"], "compared selections are "
         "executed: give --goal-policy.path and --policy.path"),
        ([*base, "--goal-policy.path", "cloth_hang", "--policy.path", str(gc_dp3), "--compare-selections",
          "consensus"], "compared selections: each rule once, and not the executed one (consensus)"),
    ]:
        assert main(argv) == 1
        assert message in capsys.readouterr().err
    assert not np.any([p.suffix == ".json" for p in tmp_path.iterdir()])
