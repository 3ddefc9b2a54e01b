"""`benchmarks/learning_curve.py --run-dir`: a finished run's checkpoints scored without training again, each row
carrying its share of the run's recorded training time and the command that reproduces the run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from lerobot_taxdpd.apps.synthetic import write_slot_dataset
from lerobot_taxdpd.recipes import recipe_path
from lerobot_taxdpd.sim.pretrain import TRAIN_SECONDS_FILE

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "learning_curve.py"


def test_a_finished_runs_checkpoints_are_scored_with_their_share_of_its_time(cli, tmp_path):
    data = write_slot_dataset(tmp_path / "slots", episodes=8, object_cloud_size=64, scene_cloud_size=128)
    run_dir = tmp_path / "run" / "train"
    cli(
        "lerobot-train",
        f"--config_path={recipe_path('taxdpd_cpu')}",
        "--dataset.repo_id=local/slots",
        f"--dataset.root={data}",
        f"--output_dir={run_dir}",
        "--policy.hidden_dim=32",
        "--policy.num_blocks=1",
        "--policy.num_object_points=64",
        "--policy.num_scene_points=128",
        "--steps=2",
        "--save_freq=1",
        "--batch_size=4",
    )
    (run_dir.parent / TRAIN_SECONDS_FILE).write_text("120.0")
    report = tmp_path / "curve.json"
    curve = [sys.executable, str(SCRIPT), "--task", "slots", "--trials", "2", "--samples", "2"]
    subprocess.run([*curve, "--run-dir", str(run_dir), "--output", str(report)], check=True, timeout=600)
    payload = json.loads(report.read_text())
    assert [row["step"] for row in payload["rows"]] == [1, 2]
    assert [row["wall_minutes"] for row in payload["rows"]] == [1.0, 2.0]
    assert all("rotation_error_deg" in row and "turn_scene_yaw_deg" in row for row in payload["rows"])
    assert payload["train_command"].startswith("lerobot-train --config_path=$(python -m lerobot_taxdpd.recipes path")
    assert "--steps=2" in payload["train_command"] and str(tmp_path) not in payload["train_command"]
    assert not (tmp_path / "run" / "train" / "checkpoints" / "000003").exists(), "scoring trains nothing"

    missing = subprocess.run([*curve, "--run-dir", str(tmp_path / "nowhere")], capture_output=True, text=True)
    assert missing.returncode != 0 and "no finished run there" in missing.stderr
