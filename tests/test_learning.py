"""It learns orientation, not only location: a seeded `lerobot-train` run on the two-slot task at full yaw
(slot and start yaws uniform on the circle) must turn the keyed box to the slot, where copying the start
orientation cannot pass, and the trained model's goal must follow the scene and ignore how the box starts.

The fast test bounds what the CI budget reaches; the slow one trains longer against the tighter bound.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lerobot_taxdpd import TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import (
    copy_start_rotation_deg,
    evaluate_slot_predictor,
    make_slot_scene,
    write_slot_dataset,
)
from lerobot_taxdpd.maths.equivariance import goal_turn_response

N_O, N_S, K = 64, 128, 8
TURN_DEG, TILT_DEG = 20.0, 10.0  # a yaw anywhere on the circle; a grasp-sized tilt
# The orientation recipe at the size of a CI run (see docs/taxdpd.md, "Learning orientation").
RECIPE = [
    "--policy.num_blocks=2",
    "--policy.num_heads=4",
    "--policy.optimizer_lr=2e-3",
    "--policy.scheduler_warmup_steps=20",
    "--policy.start_tilt_range=15",  # grasp-sized tilts; the clean-sample target and full-yaw starts are defaults
    "--batch_size=16",
]
# Bounds, per budget. Copying the start orientation is ~40 deg off (median over held-out scenes, against the
# nearer of the two slots) and any fixed orientation 90 deg: both are printed beside the result. Measured on
# this project's 2-core machines (training seeds 1 / 2 / 3): the CI run, hidden width 48, 16 neighbours a ball,
# 2000 steps: 9.7 / 11.4 / 9.8 deg (at width 64: 10.0 / 10.9 deg, a policy step of 0.166 s against 0.141; at
# width 32: 11.7 / 13.6 / 13.6 deg in 0.109 s, too near the bound); the slow run, width 64, 32 neighbours,
# 5000 steps: 4.1 deg. Shorter does not reach the bound: 1200 steps at lr 3e-3 (seed 1) left 41.7 deg.
BUDGETS = {
    "ci": dict(hidden_dim=48, steps=2000, neighbors=16, max_rotation_deg=15.0, max_translation_mm=10.0,
               min_coverage=0.6, max_turn_error_deg=5.0),
    "slow": dict(hidden_dim=64, steps=5000, neighbors=32, max_rotation_deg=5.0, max_translation_mm=6.0,
                 min_coverage=0.8, max_turn_error_deg=3.0),
}  # fmt: skip


def train_and_check(cli, tmp_path, budget: str) -> None:
    limits = BUDGETS[budget]
    dataset = write_slot_dataset(tmp_path / "slots", episodes=256, object_cloud_size=N_O, scene_cloud_size=N_S, seed=0)
    steps = limits["steps"]
    cli(
        "lerobot-train",
        "--policy.type=taxdpd",
        "--dataset.repo_id=local/taxdpd_slots",
        f"--dataset.root={dataset}",
        "--policy.push_to_hub=false",
        "--policy.device=cpu",
        *RECIPE,
        f"--policy.hidden_dim={limits['hidden_dim']}",
        f"--policy.max_neighbors={limits['neighbors']}",
        f"--steps={steps}",
        f"--save_freq={steps}",
        f"--log_freq={steps // 5}",
        "--num_workers=0",
        "--seed=1",
        f"--output_dir={tmp_path / 'run'}",
        timeout=3600,
    )
    policy = TaxDPDPolicy.from_pretrained(tmp_path / "run" / "checkpoints" / "last" / "pretrained_model")
    learnt = evaluate_slot_predictor(
        policy, num_scenes=24, num_samples=K, num_object_points=N_O, num_scene_points=N_S,
        generator=torch.Generator().manual_seed(0),
    )  # fmt: skip
    held_out = np.random.default_rng(1234)  # the same held-out scenes as evaluate_slot_predictor's
    copying = copy_start_rotation_deg([make_slot_scene(held_out, N_O, N_S, math.pi) for _ in range(24)])
    rng = np.random.default_rng(99)
    probe = [make_slot_scene(rng, N_O, N_S, math.pi) for _ in range(8)]
    obj = torch.from_numpy(np.stack([s.object_points for s in probe]))
    scene = torch.from_numpy(np.stack([s.scene_points for s in probe]))
    turns = goal_turn_response(policy, obj, scene, angle_deg=TURN_DEG, tilt_deg=TILT_DEG, num_samples=2)
    print(
        f"\n[{budget}, {steps} steps] learnt: {learnt}"
        f"\ngoal turn when the scene turns {TURN_DEG:.0f} deg (ideal {TURN_DEG:.0f}), the box alone turns "
        f"{TURN_DEG:.0f} deg or tilts {TILT_DEG:.0f} deg (ideal 0; copying: the same angle): {turns}"
        f"\nbaselines: copy the start orientation {copying:.1f} deg, any fixed orientation 90 deg; "
        f"bound {limits['max_rotation_deg']} deg"
    )

    assert copying > 2 * limits["max_rotation_deg"]  # the task cannot be passed by copying
    assert learnt["rotation_error_deg"] < limits["max_rotation_deg"]
    assert learnt["translation_error_mm"] < limits["max_translation_mm"]
    assert learnt[f"coverage@{K}"] >= limits["min_coverage"]  # both slots are sampled, precisely
    assert learnt["gmm_mass_on_slots"] > 0.9
    tolerance = limits["max_turn_error_deg"]
    assert abs(turns["scene_yaw"] - TURN_DEG) < tolerance, "the goal must turn with the scene"
    assert abs(turns["object_yaw"]) < tolerance, "turning the box alone must not turn its goal"
    assert abs(turns["object_tilt"]) < tolerance, "tilting the box alone must not tilt its goal"


@pytest.mark.long
def test_orientation_is_learnt_through_lerobot_train(cli, tmp_path):
    train_and_check(cli, tmp_path, "ci")


@pytest.mark.slow
def test_orientation_is_learnt_precisely_with_a_longer_run(cli, tmp_path):
    train_and_check(cli, tmp_path, "slow")
