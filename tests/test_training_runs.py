"""Training runs a user can trust: a seeded `lerobot-train` run reproduces its weights exactly, and two CPU
processes (torchrun, gloo) train one model together."""

from __future__ import annotations

import re

import pytest
import torch
from safetensors.torch import load_file

from conftest import BIN
from lerobot_taxdpd.apps.synthetic import write_slot_dataset
from lerobot_taxdpd.recipes import recipe_path

# The shipped CPU recipe at the CI learning test's size, so a few steps take seconds.
SMALL = [
    "--policy.hidden_dim=32",
    "--policy.num_blocks=1",
    "--policy.num_object_points=64",
    "--policy.num_scene_points=128",
]


@pytest.fixture(scope="module")
def slot_dataset(tmp_path_factory):
    return write_slot_dataset(
        tmp_path_factory.mktemp("data") / "slots", episodes=16, object_cloud_size=64, scene_cloud_size=128
    )


def _weights(run_dir):
    return load_file(run_dir / "checkpoints" / "last" / "pretrained_model" / "model.safetensors")


def test_seeded_runs_of_the_cpu_recipe_give_the_same_weights(cli, slot_dataset, tmp_path):
    """Same seed, same weights, with the recipe's own settings: its fp32 kernels and its average of the weights."""
    for name in ("a", "b"):
        cli(
            "lerobot-train",
            f"--config_path={recipe_path('taxdpd_cpu')}",
            "--dataset.repo_id=local/slots",
            f"--dataset.root={slot_dataset}",
            f"--output_dir={tmp_path / name}",
            *SMALL,
            "--steps=3",
            "--save_freq=3",
            "--batch_size=8",
            "--seed=7",
        )
    first, second = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    assert first.keys() == second.keys()
    difference = max((first[k].double() - second[k].double()).abs().max().item() for k in first)
    assert difference <= 1e-6, f"seeded runs differ by {difference}"
    assert int(first["ema_step"]) == 3, "lerobot-train moves the recipe's weight average after every step"
    moved = [k for k in first if k.startswith("ema_model.") and not torch.equal(first[k], first[k[len("ema_") :]])]
    assert moved, "the average differs from the trained weights after the first step"


@pytest.mark.slow
def test_two_cpu_processes_train_together_with_torchrun(cli, slot_dataset, tmp_path):
    """`torchrun --nproc_per_node 2 lerobot-train ...` starts two gloo ranks that share the batch and learn."""
    result = cli(
        "torchrun",
        "--nproc_per_node=2",
        str(BIN / "lerobot-train"),
        "--policy.type=taxdpd",
        "--policy.push_to_hub=false",
        "--policy.device=cpu",
        "--policy.num_heads=4",
        "--policy.max_neighbors=16",
        "--policy.optimizer_lr=2e-3",
        "--policy.scheduler_warmup_steps=10",
        *SMALL,
        "--dataset.repo_id=local/slots",
        f"--dataset.root={slot_dataset}",
        f"--output_dir={tmp_path / 'ddp'}",
        "--batch_size=8",
        "--steps=150",
        "--save_freq=150",
        "--log_freq=25",
        "--num_workers=0",
        timeout=1800,
    )
    log = result.stdout + result.stderr
    assert "Effective batch size: 8 x 2 = 16" in log
    losses = [float(x) for x in re.findall(r"step:\d+ .*?loss:([\d.]+)", log)]
    print(f"logged losses of rank 0: {losses}")
    assert len(losses) >= 4 and losses[-1] < 0.8 * losses[0]
