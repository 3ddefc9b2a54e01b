"""The README's main job, `taxdpd-demo`, as a user runs it: shipped predictors by name on held-out scenes."""

from __future__ import annotations

import json
import subprocess

from conftest import BIN, run_cli
from lerobot_taxdpd import list_goal_predictors
from lerobot_taxdpd.sim.tasks import task_names

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_demo_evaluates_a_shipped_predictor_and_writes_report_and_figures(tmp_path):
    shipped_rigid = [name for name in list_goal_predictors() if name in task_names()]
    assert shipped_rigid, "the package ships no goal predictor for a rigid task"
    task = shipped_rigid[0]
    output = tmp_path / "demo"
    result = run_cli(
        "taxdpd-demo", "--tasks", task, "--trials", "2", "--num-samples", "2", "--figures", "1", "--output", output
    )
    assert f"{task}: 2 held-out scenes" in result.stdout
    summary = json.loads((output / "summary.json").read_text())
    entry = summary["tasks"][task]
    assert entry["predictor"] == f"shipped:{task}" and 0.0 <= entry["success_rate"] <= 1.0
    report = json.loads((output / f"{task}_eval.json").read_text())
    assert report["split"] == "test" and report["trials"] == 2 and report["num_samples"] == 2
    figures = sorted(p.name for p in (output / "figures").iterdir())
    assert figures == [f"{task}_seed0_gmm.png", f"{task}_seed0_samples.png"]
    assert all((output / "figures" / name).read_bytes().startswith(PNG_SIGNATURE) for name in figures)
    # A second run replaces its own earlier output, but never a folder it did not write.
    run_cli("taxdpd-demo", "--tasks", task, "--trials", "1", "--num-samples", "1", "--figures", "0", "--output", output)
    assert json.loads((output / "summary.json").read_text())["trials_per_task"] == 1
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine")
    command = [str(BIN / "taxdpd-demo"), "--tasks", task, "--output", str(foreign)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode != 0 and "not an earlier demo's output" in result.stderr
    assert (foreign / "keep.txt").read_text() == "mine"


def test_help_lists_the_synthetic_demo_and_points_to_its_own_options():
    assert "--synthetic" in run_cli("taxdpd-demo", "--help").stdout
    assert "usage: taxdpd-demo --synthetic" in run_cli("taxdpd-demo", "--synthetic", "--help").stdout
