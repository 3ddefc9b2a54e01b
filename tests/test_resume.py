"""A `lerobot-train` run killed with SIGKILL resumes (`--resume=true`) to the model an uninterrupted run trains.

Both runs are seeded. LeRobot restores the step, optimizer, scheduler and RNG states of the last checkpoint
and rebuilds the data loader, whose first shuffle then draws from the restored RNG: with checkpoints at epoch
boundaries that is the very draw the uninterrupted run makes there, so the resumed run repeats it batch for
batch, augmentation included, and must end with the same weights, weight average, optimizer and schedule.
(A checkpoint inside an epoch resumes with a fresh shuffle: not bit-equal, and not claimed here.) Before
resuming, the next checkpoint is left half-written, as a kill while LeRobot writes it would leave it: it is
refused by name, and the resume from the previous one completes over it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from conftest import BIN, TINY_GC_DP3, TINY_TAXDPD
from lerobot_taxdpd import TaxDPDPolicy
from lerobot_taxdpd.apps.synthetic import write_slot_dataset
from lerobot_taxdpd.policies.checkpoints import CheckpointError
from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy
from lerobot_taxdpd.recipes import recipe_path
from test_gc_dp3_train import write_goal_side_dataset

#: Largest absolute difference allowed between the two runs' tensors: same kernels, same inputs, one thread.
TOLERANCE = 1e-6


def _command(dataset: Path, repo_id: str, output_dir: Path, policy: list[str], steps: int, save_freq: int, batch):
    return [
        str(BIN / "lerobot-train"),
        *policy,
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={dataset}",
        "--policy.push_to_hub=false",
        "--policy.use_ema=true",
        f"--batch_size={batch}",
        f"--steps={steps}",
        f"--save_freq={save_freq}",
        "--log_freq=1",
        "--num_workers=0",
        "--seed=3",
        f"--output_dir={output_dir}",
    ]


def _run(command: list[str]) -> None:
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, env=_env())
    assert result.returncode == 0, result.stderr[-4000:]


def _env() -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1"}


def _kill_after_first_checkpoint(command: list[str], output_dir: Path, first: int) -> None:
    """Start the run and SIGKILL it as soon as its first checkpoint is complete (`last` points at it)."""
    last = output_dir / "checkpoints" / "last"
    with subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env()) as process:
        deadline = time.monotonic() + 600
        while not (last.is_symlink() and os.readlink(last) == f"{first:06d}") and process.poll() is None:
            assert time.monotonic() < deadline, "no checkpoint within 10 minutes"
            time.sleep(0.01)
        process.send_signal(signal.SIGKILL)
        assert process.wait() == -signal.SIGKILL, "the run ended before it could be killed"


def _leave_a_half_written_checkpoint(run: Path, step: int, policy_class) -> None:
    """What a kill while LeRobot writes checkpoint `step` leaves: its config, weights cut short, no training
    state yet, and `last` still on the previous checkpoint (LeRobot moves it once a checkpoint is complete)."""
    complete = run / "checkpoints" / "last" / "pretrained_model"
    partial = run / "checkpoints" / f"{step:06d}" / "pretrained_model"
    partial.mkdir(parents=True)
    shutil.copy(complete / "config.json", partial)
    weights = (complete / "model.safetensors").read_bytes()
    (partial / "model.safetensors").write_bytes(weights[: len(weights) // 3])
    with pytest.raises(CheckpointError, match="model.safetensors: not a readable safetensors file"):
        policy_class.from_pretrained(partial)


def _state(run: Path, step: int) -> dict:
    """Everything a checkpoint holds: weights (with the average), optimizer tensors, step and schedule."""
    folder = run / "checkpoints" / f"{step:06d}"
    training = folder / "training_state"
    return {
        "weights": load_file(folder / "pretrained_model" / "model.safetensors"),
        "optimizer": load_file(training / "optimizer_state.safetensors"),
        "optimizer_groups": json.loads((training / "optimizer_param_groups.json").read_text()),
        "scheduler": json.loads((training / "scheduler_state.json").read_text()),
        "step": json.loads((training / "training_step.json").read_text()),
    }


def _largest_difference(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> float:
    assert a.keys() == b.keys()
    return max((a[k].double() - b[k].double()).abs().max().item() for k in a if a[k].numel())


def _assert_resumes_to_the_uninterrupted_run(tmp_path, dataset, repo_id, policy, steps, save_freq, batch, policy_class):
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    _run(_command(dataset, repo_id, straight, policy, steps, save_freq, batch))
    _kill_after_first_checkpoint(_command(dataset, repo_id, killed, policy, steps, save_freq, batch), killed, save_freq)
    resumed_from = (killed / "checkpoints" / "last").resolve().name
    _leave_a_half_written_checkpoint(killed, int(resumed_from) + save_freq, policy_class)
    config = killed / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    _run([str(BIN / "lerobot-train"), f"--config_path={config}", "--resume=true"])

    expected, got = _state(straight, steps), _state(killed, steps)
    weights, optimizer = (_largest_difference(expected[k], got[k]) for k in ("weights", "optimizer"))
    print(f"\nresumed from step {resumed_from}: weights differ by {weights:.2e}, optimizer state by {optimizer:.2e}")
    assert got["step"] == expected["step"] == {"step": steps}
    assert got["scheduler"] == expected["scheduler"], "the schedule resumes where it stopped"
    assert got["optimizer_groups"] == expected["optimizer_groups"]
    assert int(got["weights"]["ema_step"]) == steps, "the weight average saw every step, before and after the kill"
    assert weights <= TOLERANCE and optimizer <= TOLERANCE


@pytest.mark.slow
def test_taxdpd_cpu_recipe_killed_after_a_checkpoint_resumes_to_the_same_model(tmp_path):
    """The CPU recipe (weight average, warm-up then cosine schedule, fp32) at a tiny size: 16 frames, 4 a batch."""
    dataset = write_slot_dataset(tmp_path / "slots", episodes=8, object_cloud_size=32, scene_cloud_size=64)
    policy = [
        f"--config_path={recipe_path('taxdpd_cpu')}",
        *TINY_TAXDPD,
        "--policy.num_object_points=32",
        "--policy.num_scene_points=64",
        "--policy.scheduler_warmup_steps=2",
    ]
    _assert_resumes_to_the_uninterrupted_run(
        tmp_path, dataset, "local/slots", policy, steps=12, save_freq=4, batch=4, policy_class=TaxDPDPolicy
    )


@pytest.mark.slow
def test_gc_dp3_killed_after_a_checkpoint_resumes_to_the_same_model(tmp_path):
    """gc_dp3 with its weight average: 48 frames, 8 a batch, a checkpoint every epoch."""
    dataset = write_goal_side_dataset(tmp_path / "goal_side")
    _assert_resumes_to_the_uninterrupted_run(
        tmp_path, dataset, "local/goal_side", TINY_GC_DP3, steps=12, save_freq=6, batch=8, policy_class=GcDp3Policy
    )
