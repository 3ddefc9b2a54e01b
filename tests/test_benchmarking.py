"""The JSON records that every benchmark and evaluation writes."""

import argparse
import json
from pathlib import Path

import pytest

from lerobot_taxdpd.reports.benchmarking import write_json


def test_write_json_records_command_line_paths_as_text(tmp_path):
    parser = argparse.ArgumentParser()
    parser.add_argument("--dataset", type=Path)
    arguments = vars(parser.parse_args(["--dataset", "data/mug_easyrack"]))
    path = write_json(tmp_path / "speed.json", {"arguments": arguments, "step_s": 0.5})
    assert json.loads(path.read_text()) == {"arguments": {"dataset": "data/mug_easyrack"}, "step_s": 0.5}


def test_write_json_refuses_other_objects_and_keeps_the_previous_file(tmp_path):
    path = write_json(tmp_path / "speed.json", {"step_s": 0.5})
    with pytest.raises(TypeError, match="object is not JSON serializable"):
        write_json(path, {"step_s": object()})
    assert json.loads(path.read_text()) == {"step_s": 0.5}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["speed.json"]
