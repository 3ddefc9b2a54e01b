"""`benchmarks/gpu_train.py` dry-run on the CPU: two tasks side by side at a tiny size, a few steps each."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_taxdpd import load_goal_predictor
from lerobot_taxdpd.apps.synthetic import write_slot_dataset

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "gpu_train.py"
TINY = [
    "--device=cpu",
    "--batch=4",
    "--hidden=16",
    "--blocks=1",
    "--heads=2",
    "--neighbors=16",
    "--object-points=32",
    "--scene-points=64",
    "--no-amp",
    "--num-workers=0",
    "--warmup-steps=4",
    "--alone-steps=4",
    "--max-steps=6",
]


@pytest.mark.slow
def test_a_cpu_dry_run_leaves_each_task_a_checkpoint_a_log_and_its_speed(tmp_path):
    pairs = []
    for seed, task in enumerate(("mug_easyrack", "insert_waterproof")):
        root = write_slot_dataset(tmp_path / task, episodes=4, object_cloud_size=32, scene_cloud_size=64, seed=seed)
        pairs.append(f"--dataset={task}={root}")
    output = tmp_path / "gpu_train"
    command = [sys.executable, str(SCRIPT), *pairs, *TINY, f"--output={output}", "--budget-s=300"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-5000:]

    report = json.loads((output / "gpu_train.json").read_text())
    assert report["machine"]["torch"] and report["machine"]["gpu"]
    assert report["launches"]["training_step"]["ops"] > 0
    assert [r["task"] for r in report["phases"]["alone"]["runs"]] == ["mug_easyrack"]
    runs = {r["task"]: r for r in report["phases"]["main"]["runs"]}
    assert set(runs) == {"mug_easyrack", "insert_waterproof"} and report["phases"]["main"]["side_by_side"]
    assert "--policy.start_yaw_range=0" in runs["insert_waterproof"]["command"]  # the task's own flags
    for run in runs.values():
        assert run["steps_per_s"] > 0 and run["samples_per_s"] == pytest.approx(4 * run["steps_per_s"])
        assert run["checkpoint_step"] == run["steps_requested"] == 6
        assert "updt_s:" in Path(tmp_path, run["log"]).read_text()
        assert load_goal_predictor(run["checkpoint"]).config.hidden_dim == 16
    assert "steps/s" in result.stdout
