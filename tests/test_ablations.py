"""The ablation table as a user runs it: `benchmarks/ablations.py` drives `sim pretrain` once per variant."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import draccus

from conftest import tiny_taxdpd_recipe
from lerobot_taxdpd import TaxDPDConfig
from lerobot_taxdpd.sim.pretrain import training_flags
from lerobot_taxdpd.sim.tasks import get_task

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str | Path) -> subprocess.CompletedProcess:
    command = [sys.executable, *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=ROOT)


def test_ablation_runner_trains_each_switch_on_shared_demos_and_writes_the_table(tmp_path):
    output = tmp_path / "ablations"
    recipe = tiny_taxdpd_recipe(tmp_path / "tiny.json")
    args = [
        ROOT / "benchmarks" / "ablations.py", "--tasks", "book_shelf", "--variants", "full", "no_gmm", "--steps", "2",
        "--episodes", "4", "--trials", "2", "--num-samples", "2", "--config", recipe,
        "--output", output, "--set", "frame_noise_std=0.3",  # a task's recipe flag, given to every cell
    ]
    result = run(*args)
    assert result.returncode == 0, result.stderr[-4000:]
    rows = json.loads(output.with_suffix(".json").read_text())["rows"]
    assert [(r["variant"], r["paper_row"]) for r in rows] == [("full", "TAX-DPD"), ("no_gmm", "w/o GMM")]
    assert all(r["paper_success_rate"] is not None and 0 <= r["success_rate"] <= 1 for r in rows)
    assert all(r["coverage"] is not None for r in rows)  # book_shelf has several valid goals
    assert rows[0]["winner_take_all_rmse_vs_full"] is None
    paired = rows[1]["winner_take_all_rmse_vs_full"]  # same seeds, so the difference is per scene
    assert paired["ci95_mm"][0] <= paired["mean_mm"] <= paired["ci95_mm"][1]
    table = output.with_suffix(".md").read_text()
    assert "| book_shelf | w/o GMM (`no_gmm`) |" in table  # the detailed table
    summary = [line for line in table.splitlines() if line.startswith("| w/o GMM (`no_gmm`) | ")]
    assert summary and summary[0].endswith("| 0.75 |")  # one line a variant, the paper's Book/Shelf beside it

    task = output / "book_shelf"
    assert (task / "data" / "meta" / "info.json").is_file() and not (task / "full" / "data").exists()
    for variant, use_gmm in (("full", True), ("no_gmm", False)):
        checkpoint = task / variant / "train" / "checkpoints" / "last" / "pretrained_model"
        config = json.loads((checkpoint / "config.json").read_text())
        assert config["use_gmm"] is use_gmm and config["frame_noise_std"] == 0.3
        metrics = json.loads((task / variant / "metrics.json").read_text())
        assert ("--policy.use_gmm=false" in metrics["training_command"]) is not use_gmm
        gmm_maps = list((task / variant / "figures").glob("*_gmm.png"))
        assert bool(gmm_maps) is use_gmm  # a model without the Dense GMM has no weight map to draw

    # A rerun reuses every finished cell instead of training again.
    finished = (task / "no_gmm" / "metrics.json").stat().st_mtime_ns
    assert run(*args).returncode == 0
    assert (task / "no_gmm" / "metrics.json").stat().st_mtime_ns == finished
    # A finished cell is reused only by its own command, not by a run with other flags.
    other = run(
        "-m", "lerobot_taxdpd.sim", "pretrain", "--task", "book_shelf", "--config", tmp_path / "tiny.json",
        "--steps", "2", "--episodes", "4", "--dataset", task / "data", "--output", task / "no_gmm",
        "--policy.use_gmm=true",
    )
    assert "[1/4] reusing the 4 book_shelf demonstrations" in other.stdout  # the same options: said, not silent
    assert other.returncode == 1 and "trained by another command" in other.stderr and "--overwrite" in other.stderr
    # --report-only tabulates what has finished and starts nothing.
    result = run(*args[:6], "mlp_encoder", *args[6:], "--report-only")
    assert result.returncode == 0, result.stderr[-4000:]
    assert len(json.loads(output.with_suffix(".json").read_text())["rows"]) == 2
    assert not (task / "mlp_encoder").exists()


def test_pretrain_passes_only_policy_flags_on_to_lerobot_train():
    result = run("-m", "lerobot_taxdpd.sim", "pretrain", "--task", "book_shelf", "--seed=1", "--bogus=1")
    assert result.returncode == 2 and "unrecognized arguments: --bogus=1\n" in result.stderr
    result = run(
        "-m", "lerobot_taxdpd.sim", "eval", "--task", "book_shelf", "--predictor", "oracle", "--policy.use_gmm=false"
    )
    assert result.returncode == 2 and "unrecognized arguments: --policy.use_gmm=false" in result.stderr


def test_the_summary_ranks_variants_by_their_success():
    spec = importlib.util.spec_from_file_location("ablations", ROOT / "benchmarks" / "ablations.py")
    ablations = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ablations)

    def row(variant: str, success: float) -> dict:
        versus = None if variant == "full" else {"mean_mm": 1.0, "ci95_mm": [0.5, 1.5]}
        return {
            "task": "mug_medrack", "variant": variant, "success_rate": success, "success_ci95": [0.0, 1.0],
            "winner_take_all_rmse_mm": 8.0, "winner_take_all_rmse_vs_full": versus,
        }

    table = ablations.summary_markdown([row("full", 0.66), row("tax3d_style", 0.0), row("no_gmm", 0.7)])
    ranked = [line.split(" (`")[1].split("`")[0] for line in table.splitlines()[2:]]
    assert ranked == ["no_gmm", "full", "tax3d_style"]


def test_ablation_overrides_must_name_a_field_and_a_value():
    result = run(ROOT / "benchmarks" / "ablations.py", "--set", "frame_noise_std", "--report-only")
    assert result.returncode == 2 and "--set: expected FIELD=VALUE, got frame_noise_std" in result.stderr


def test_a_task_trains_with_its_own_flags_and_the_users_win():
    """Insertion drops the plug's yaw augmentation (one grasp yaw in every scene), the mugs theirs (symmetric goals,
    demos at every start yaw), the book turns its scene as far as shelves turn; a user's flag overrides a task's."""
    flags = training_flags(get_task("insert_waterproof"), 500, ["--policy.start_yaw_range=5"])
    assert flags[0] == "--steps=500"
    config = draccus.parse(
        config_class=TaxDPDConfig, args=[flag.replace("--policy.", "--") for flag in flags[1:]]
    )  # the same parser lerobot-train uses, which keeps the last of repeated flags
    assert (config.start_yaw_range, config.start_tilt_range) == (5.0, 15.0)
    assert training_flags(get_task("mug_easyrack"), None, []) == ["--policy.start_yaw_range=0"]
    assert training_flags(get_task("can_cabinet"), None, []) == []  # the recipe's full-yaw default stands
    assert training_flags(get_task("book_shelf"), None, []) == [
        "--policy.start_yaw_range=0",
        "--policy.z_rotation_range=30",  # the shelves keep a heading: the scene turn spans +-30 deg
    ]
