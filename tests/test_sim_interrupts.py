"""`sim generate` and `sim eval` killed midway (SIGKILL: no handler, no clean-up) leave nothing that a later run
reads as whole: no dataset at --root, no report; what an earlier run wrote stays as it was, and a rerun completes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from convert_fixtures import leftovers

TASK = "mug_easyrack"


def _sim(*args: str) -> list[str]:
    return [sys.executable, "-m", "lerobot_taxdpd.sim", *args]


def _run(command: list[str]) -> None:
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, env=_env())
    assert result.returncode == 0, result.stderr[-4000:]


def _env() -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1"}


def _kill_midway(command: list[str], started) -> None:
    """Run `command` until `started()` says it is midway through its work, then SIGKILL it."""
    with subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env()) as process:
        deadline = time.monotonic() + 300
        while not started() and process.poll() is None:
            assert time.monotonic() < deadline, "the command never got going"
            time.sleep(0.05)
        time.sleep(1.0)  # some episodes or trials into the work
        process.send_signal(signal.SIGKILL)
        assert process.wait() == -signal.SIGKILL, "the command finished before it could be killed"


def _files(folder: Path) -> dict[Path, bytes]:
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _generate(root: Path, episodes: int, *extra: str) -> list[str]:
    return _sim(
        "generate", "--task", TASK, "--episodes", str(episodes), "--repo-id", "me/mugs", "--root", str(root), *extra
    )


@pytest.mark.slow
def test_a_killed_generate_leaves_no_dataset_and_the_previous_one_untouched(tmp_path):
    root = tmp_path / "mugs"
    _kill_midway(_generate(root, 200), lambda: bool(leftovers(root)))
    assert not root.exists(), "nothing at --root until the dataset is complete"

    _run(_generate(root, 2))  # the rerun completes beside the killed run's hidden staging folder
    assert LeRobotDataset("me/mugs", root=root).meta.total_episodes == 2
    before = _files(root)

    staged = set(leftovers(root))
    _kill_midway(_generate(root, 200, "--overwrite"), lambda: set(leftovers(root)) - staged)
    assert _files(root) == before, "--overwrite replaces the dataset only once the new one is complete"
    assert LeRobotDataset("me/mugs", root=root).meta.total_episodes == 2


def _new_figure(output: Path):
    """A check that the evaluation has drawn a trial since now: it is past its start-up, among the trials."""
    since = time.time()
    return lambda: any(p.stat().st_mtime > since for p in (output / "figures").glob("*.png"))


@pytest.mark.slow
def test_a_killed_eval_leaves_no_report_and_the_previous_one_untouched(tmp_path):
    output = tmp_path / "eval"
    report = output / f"{TASK}_eval.json"

    def evaluate(trials: int) -> list[str]:
        return _sim("eval", "--task", TASK, "--predictor", "oracle", "--trials", str(trials), "--output", str(output))

    _kill_midway(evaluate(500), _new_figure(output))
    assert not report.exists(), "no report until every trial is done"

    _run(evaluate(2))
    before = report.read_bytes()
    assert json.loads(before)["success"]["trials"] == 2

    _kill_midway(evaluate(500), _new_figure(output))
    assert report.read_bytes() == before, "the previous report stays until the new one is written whole"
