"""`taxdpd-convert samples`, where the README's and docs/converters.md's converter commands start: it writes a
few raw demos of every layout, and each folder converts, by the command the tool prints, into a dataset that
LeRobot's own `LeRobotDataset` reads."""

from __future__ import annotations

import shlex
from pathlib import Path

from lerobot.datasets.lerobot_dataset import LeRobotDataset

from conftest import run_cli
from datasets_conv.__main__ import main
from datasets_conv.samples import conversion_commands
from lerobot_taxdpd.data.schema import ACTION_KEY, GOAL_CLOUD_KEY, OBJECT_KEY, SCENE_KEY
from test_readme_commands import README, REPO, fenced_commands, split_command

#: Episodes each conversion writes from `--demos 3`: the training split holds all but the held-out demo.
EPISODES = {"rpdiff": 2, "rpdiff_chunked": 3, "cloth_goals": 2, "cloth_rollouts": 2, "nist": 2, "nist_teach": 3}


def _printed_commands(stdout: str) -> list[list[str]]:
    """The `taxdpd-convert` arguments of each command the samples command prints."""
    return [shlex.split(line)[1:] for line in stdout.splitlines() if line.startswith("  taxdpd-convert ")]


def _value(argv: list[str], flag: str) -> str:
    return argv[argv.index(flag) + 1]


def test_every_sample_layout_converts_into_a_dataset_lerobot_reads(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = run_cli("taxdpd-convert", "samples", "--out", "raw_samples", "--demos", "3")
    commands = _printed_commands(result.stdout)
    assert {_value(argv, "--repo-id").removeprefix("me/sample_") for argv in commands} == set(EPISODES)
    for argv in commands:
        assert main(argv) == 0, argv
        dataset = LeRobotDataset(_value(argv, "--repo-id"), root=_value(argv, "--root"))
        assert dataset.num_episodes == EPISODES[_value(argv, "--repo-id").removeprefix("me/sample_")]
        frame = dataset[0]
        goal = GOAL_CLOUD_KEY if _value(argv, "--repo-id").endswith("rollouts") else ACTION_KEY
        for key in (OBJECT_KEY, SCENE_KEY, goal):
            assert frame[key].ndim == 2 and frame[key].shape[1] == 3, (argv, key)
        assert frame[goal].shape == frame[OBJECT_KEY].shape


def test_samples_refuses_a_folder_that_holds_other_files(tmp_path, capsys):
    (tmp_path / "mine.txt").write_text("")
    assert main(["samples", "--out", str(tmp_path)]) == 1
    assert "is not an empty folder" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]


def test_the_docs_convert_samples_with_the_commands_the_samples_command_prints():
    printed = [["taxdpd-convert", *argv] for argv in conversion_commands(Path("raw_samples"))]
    for page in (README, REPO / "docs" / "converters.md"):
        commands = [split_command(c.text) for c in fenced_commands(page)]
        samples = commands.index(["taxdpd-convert", "samples", "--out", "raw_samples"])
        tried = [words for words in commands[samples + 1 :] if "--raw-dir" in words]
        tried = [words for words in tried if _value(words, "--raw-dir").startswith("raw_samples/")]
        assert tried and all(words in printed for words in tried), page
