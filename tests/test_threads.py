"""The package's commands run on one torch thread unless the user says otherwise (--threads, or OMP_NUM_THREADS
already set), and hand the choice on to the processes they start; the report records it."""

from __future__ import annotations

import json
import os

import pytest
import torch

from lerobot_taxdpd.sim.cli import main


@pytest.fixture
def restored_threads(monkeypatch):
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)  # restored after the test, like torch's own count
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


@pytest.mark.parametrize(
    ("environment", "flag", "expected"),
    [({}, [], 1), ({"OMP_NUM_THREADS": "2"}, [], 2), ({"OMP_NUM_THREADS": "2"}, ["--threads", "3"], 3)],
)
def test_the_thread_count_is_one_unless_told(restored_threads, monkeypatch, tmp_path, environment, flag, expected):
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    argv = ["eval", "--task", "insert_ssd", "--predictor", "oracle", "--trials", "1", "--figures", "0"]
    assert main([*argv, "--output", str(tmp_path), *flag]) == 0
    report = json.loads((tmp_path / "insert_ssd_eval.json").read_text())
    assert report["machine"]["torch_threads"] == expected
    assert os.environ["OMP_NUM_THREADS"] == str(expected)  # what worker processes and lerobot-train inherit


def test_a_thread_count_below_one_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "--task", "insert_ssd", "--predictor", "oracle", "--threads", "0"])
    assert "--threads: must be at least 1" in capsys.readouterr().err
