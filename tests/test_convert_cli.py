"""The `taxdpd-convert` / `python -m datasets_conv` CLI as a user runs it: help, summary, errors, Hub, interrupts.

Entry points, the top-level help and interrupts run as subprocesses; the other cases call the same `main()`
in-process, which spares each case the several seconds of importing LeRobot and torch again.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from conftest import BIN, TINY_TAXDPD, run_cli
from convert_fixtures import leftovers
from datasets_conv.__main__ import main
from datasets_conv.rpdiff import RPDIFF_TASKS
from datasets_conv.samples import (
    dedo_goal_demo,
    nist_demo,
    rpdiff_demo,
    save_dedo_goal_demo,
    save_nist_npz,
    save_rpdiff_demo,
)


def convert(*args, module: bool = False) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "datasets_conv"] if module else [str(BIN / "taxdpd-convert")]
    return subprocess.run([*command, *map(str, args)], capture_output=True, text=True, timeout=300)


def _rpdiff_dir(tmp_path: Path, count: int) -> Path:
    demo_dir = tmp_path / "mug_rack_easy_single" / "task_name_mug_on_rack"
    rng = np.random.default_rng(0)
    for i in range(count):
        save_rpdiff_demo(demo_dir / f"demo_aug_{i}.npz", rpdiff_demo(rng, nested_pose=i % 2 == 1)[0])
    return demo_dir


def test_help_explains_layouts_and_the_pickle_risk(capsys):
    top = convert("--help")  # through the installed entry point; the subcommands' help in-process
    assert top.returncode == 0 and all(s in top.stdout for s in ("rpdiff", "dedo", "nist", "push", "HF_TOKEN"))

    def help_of(command: str) -> str:
        with pytest.raises(SystemExit) as stop:
            main([command, "--help"])
        assert stop.value.code == 0
        return capsys.readouterr().out

    rpdiff = help_of("rpdiff")
    assert "WARNING" in rpdiff and "execute code" in rpdiff and "split_info" in rpdiff
    assert all(name in rpdiff for name in RPDIFF_TASKS)
    assert "--kind" in help_of("dedo")
    nist = help_of("nist")
    assert "goal_tf" in nist and "--units" in nist and "--holdout-fraction" in nist


def test_convert_prints_summary_and_lerobot_loads_and_trains_on_the_result(tmp_path):
    root = tmp_path / "out"
    result = convert(
        "rpdiff", "--raw-dir", _rpdiff_dir(tmp_path, 3), "--repo-id", "me/rpdiff_mug_easyrack", "--root", root,
        "--frames-per-episode", "3", module=True,
    )
    assert result.returncode == 0, result.stderr
    for line in ("demos read : 3", "converted  : 3 episodes, 9 frames", "skipped    : 0", f"output     : {root}"):
        assert line in result.stdout
    dataset = LeRobotDataset("me/rpdiff_mug_easyrack", root=root)
    assert dataset.meta.total_episodes == 3 and list(dataset.meta.episodes["length"]) == [3, 3, 3]
    assert "taxdpd-convert rpdiff --raw-dir" in (root / "README.md").read_text()
    run_cli(
        "lerobot-train", "--policy.type=taxdpd", "--dataset.repo_id=me/rpdiff_mug_easyrack", f"--dataset.root={root}",
        "--policy.push_to_hub=false", "--steps=2", "--batch_size=2", "--num_workers=0", *TINY_TAXDPD,
        f"--output_dir={tmp_path / 'train'}",
    )
    assert (tmp_path / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file()


def test_bad_demo_fails_cleanly_and_skip_invalid_lists_it(tmp_path, capsys):
    demo_dir = _rpdiff_dir(tmp_path, 3)
    (demo_dir / "demo_aug_1.npz").write_bytes((demo_dir / "demo_aug_1.npz").read_bytes()[:5000])
    root = tmp_path / "out"
    args = ["rpdiff", "--raw-dir", str(demo_dir), "--repo-id", "me/x", "--root", str(root)]

    assert main(args) == 1
    stderr = capsys.readouterr().err
    assert "demo_aug_1.npz" in stderr and "--skip-invalid" in stderr
    assert not root.exists() and leftovers(root) == []

    assert main([*args, "--skip-invalid"]) == 0
    stdout = capsys.readouterr().out
    assert "skipped    : 1" in stdout and "demo_aug_1.npz: not a readable .npz file" in stdout
    assert "Skipped inputs (1)" in (root / "README.md").read_text()

    assert main(args) == 1 and "already exists" in capsys.readouterr().err
    assert LeRobotDataset("me/x", root=root).meta.total_episodes == 2


def test_a_raw_dir_one_level_too_high_points_at_the_layout_below(tmp_path, capsys):
    """The common slip names where the demos are, and does not suggest --skip-invalid, which cannot help."""
    rng = np.random.default_rng(0)
    rpdiff = tmp_path / "task_demos" / "mug_rack_easy_single" / "task_name_mug_on_rack"
    save_rpdiff_demo(rpdiff / "demo_aug_0.npz", rpdiff_demo(rng)[0])
    save_nist_npz(tmp_path / "nist" / "teach" / "waterproof" / "0.npz", *nist_demo(rng)[:3])
    save_dedo_goal_demo(tmp_path / "dedo" / "demos" / "train_tax3d" / "demo_0.npz", dedo_goal_demo(rng))
    for source, too_high, layout in [
        (["rpdiff"], tmp_path / "task_demos", rpdiff),
        (["nist"], tmp_path / "nist", tmp_path / "nist" / "teach"),
        (["dedo", "--kind", "goal"], tmp_path / "dedo", tmp_path / "dedo" / "demos"),
    ]:
        args = [*source, "--raw-dir", str(too_high), "--repo-id", "me/x", "--root", str(tmp_path / "out")]
        assert main(args) == 1
        error = capsys.readouterr().err
        assert f"it is further down, in {layout}: point --raw-dir there" in error, error
        assert "--skip-invalid" not in error


def test_push_offline_keeps_the_dataset_and_says_how_to_retry(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for i in range(2):
        initial, socket, goal_tf, _ = nist_demo(rng)
        save_nist_npz(tmp_path / "nist" / "waterproof" / f"{i}.npz", initial, socket, goal_tf)
    root = tmp_path / "out"
    args = ["--raw-dir", str(tmp_path / "nist"), "--repo-id", "me/nist", "--root", str(root), "--license", "mit"]

    assert main(["nist", *args, "--push", "--private"]) == 1
    result = capsys.readouterr()
    assert "converted  : 2 episodes" in result.out
    assert "Offline" in result.err, "the upload must reach huggingface_hub, which refuses offline"
    assert "HF_HUB_OFFLINE is set" in result.err and "hf auth login" not in result.err  # the cause, not a login
    assert f"taxdpd-convert push --root {root} --repo-id me/nist --private" in result.err
    readme = (root / "README.md").read_text()
    assert "license: mit" in readme and "- taxdpd" in readme and "- nist" in readme
    assert LeRobotDataset("me/nist", root=root).meta.total_episodes == 2

    assert main(["push", "--root", str(root), "--repo-id", "me/nist"]) == 1
    assert "Offline" in capsys.readouterr().err
    # Online but with no Hub to reach (a closed local port stands in for a dead network): the network is named.
    env = {**os.environ, "HF_HUB_OFFLINE": "0", "HF_ENDPOINT": "http://127.0.0.1:9", "HF_TOKEN": "hf_unused"}
    command = [str(BIN / "taxdpd-convert"), "push", "--root", str(root), "--repo-id", "me/nist"]
    unreachable = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert unreachable.returncode == 1 and "The Hub could not be reached" in unreachable.stderr


def test_interrupt_leaves_the_previous_dataset_untouched(tmp_path):
    """Ctrl-C while a new dataset is being written over an old one (--overwrite) leaves the old one as it was."""
    root = tmp_path / "out"
    small = _rpdiff_dir(tmp_path / "small", 2)
    assert main(["rpdiff", "--raw-dir", str(small), "--repo-id", "me/x", "--root", str(root)]) == 0
    before = {p.relative_to(root): p.stat().st_size for p in root.rglob("*")}
    big = _rpdiff_dir(tmp_path / "big", 60)
    command = [str(BIN / "taxdpd-convert"), "rpdiff", "--raw-dir", str(big), "--repo-id", "me/x", "--root", str(root)]
    # 40 samplings a demo keep the new dataset half-written for about 13 s (2 a demo gave a window of about 2 s,
    # which a loaded CI machine once let pass unseen); the run is interrupted at once, so it costs nothing.
    slow = [*command, "--overwrite", "--frames-per-episode", "40"]
    # A shell starts background jobs with SIGINT ignored, and a child would inherit that: give it Ctrl-C back.
    process = subprocess.Popen(
        slow, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    while not leftovers(root) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    seen_half_written = leftovers(root)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)

    assert process.returncode == 130 and "interrupted" in stderr, (seen_half_written, process.returncode, stderr)
    assert {p.relative_to(root): p.stat().st_size for p in root.rglob("*")} == before
    assert leftovers(root) == [] and LeRobotDataset("me/x", root=root).meta.total_episodes == 2
