"""It learns: a seeded `lerobot-train` run on the two-slot task puts the GMM's mass on the slots and
samples goals in both slots, within stated error bounds, far better than the same model untrained."""

from __future__ import annotations

import copy

import torch

from lerobot_taxdpd import TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import evaluate_slot_predictor, write_slot_dataset

N_O, N_S, K = 64, 128, 8
STEPS = 500
# Stated bounds for this budget (a 6 cm keyed box, slots >= 15 cm apart; an untrained model is ~10x worse).
MAX_TRANSLATION_MM = 15.0
MAX_ROTATION_DEG = 5.0
MIN_GMM_MASS = 0.5
MIN_COVERAGE = 0.6


def test_two_slot_task_is_learnt_through_lerobot_train(cli, tmp_path):
    dataset = write_slot_dataset(
        tmp_path / "slots", episodes=128, object_cloud_size=N_O, scene_cloud_size=N_S, yaw_range=0.0, seed=0
    )
    cli(
        "lerobot-train",
        "--policy.type=taxdpd",
        "--dataset.repo_id=local/taxdpd_slots",
        f"--dataset.root={dataset}",
        "--policy.push_to_hub=false",
        "--policy.device=cpu",
        "--policy.hidden_dim=32",
        "--policy.num_blocks=1",
        "--policy.num_heads=4",
        "--policy.max_neighbors=32",
        "--policy.optimizer_lr=2e-3",
        "--policy.scheduler_warmup_steps=20",
        "--batch_size=16",
        f"--steps={STEPS}",
        f"--save_freq={STEPS}",
        "--log_freq=100",
        "--num_workers=0",
        "--seed=1",
        f"--output_dir={tmp_path / 'run'}",
        timeout=900,
    )
    policy = TaxDPDPolicy.from_pretrained(tmp_path / "run" / "checkpoints" / "last" / "pretrained_model")
    task = dict(num_samples=K, num_object_points=N_O, num_scene_points=N_S, yaw_range=0.0)
    learnt = evaluate_slot_predictor(policy, **task, generator=torch.Generator().manual_seed(0))

    torch.manual_seed(1)
    untrained = evaluate_slot_predictor(TaxDPDPolicy(copy.deepcopy(policy.config)).eval(), **task)
    print(f"learnt: {learnt}\nuntrained: {untrained}")

    assert learnt["gmm_mass_on_slots"] > MIN_GMM_MASS > untrained["gmm_mass_on_slots"]
    assert learnt[f"coverage@{K}"] >= MIN_COVERAGE  # both slots are sampled, precisely
    assert learnt["translation_error_mm"] < MAX_TRANSLATION_MM < untrained["translation_error_mm"]
    assert learnt["rotation_error_deg"] < MAX_ROTATION_DEG
    assert learnt["translation_error_mm"] < untrained["translation_error_mm"] / 5
