"""NIST converter: the goal_tf convention, millimetre teach data read with open3d, units, the seeded split."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from convert_fixtures import leftovers, row_indices
from datasets_conv.nist import convert_nist, split_demos
from datasets_conv.pipeline import ConversionOptions
from datasets_conv.raw_io import DemoError
from datasets_conv.samples import nist_demo, save_nist_npz, save_nist_teach
from lerobot_taxdpd.data.dataset_writer import read_card_info
from lerobot_taxdpd.data.schema import ACTION_KEY, GOAL_TRANSFORM_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.data.validation import PointCloudError


def _check_goals(dataset: LeRobotDataset, truth: list[tuple[str, np.ndarray, np.ndarray]]) -> None:
    """Episode e is truth[e] = (task, initial plug, true goal plug): goal rows are the true inserted plug rows
    at the same indices, and action == T* object."""
    for i in range(len(dataset)):
        item = dataset[i]
        task, initial, goal = truth[int(item["episode_index"])]
        assert item["task"] == task
        rows = row_indices(item[OBJECT_KEY].numpy(), initial)
        np.testing.assert_allclose(item[ACTION_KEY].numpy(), goal[rows], atol=2e-6)
        transform = item[GOAL_TRANSFORM_KEY].numpy().astype(np.float64)
        np.testing.assert_allclose(
            item[OBJECT_KEY].numpy() @ transform[:3, :3].T + transform[:3, 3], item[ACTION_KEY].numpy(), atol=1e-6
        )


def test_npz_split_folders_and_goal_tf_convention(tmp_path):
    rng = np.random.default_rng(0)
    truth = []
    for connector in ("dsub25", "waterproof"):  # episodes follow the connectors' natural order
        for split, count in (("train", 2), ("test", 1)):
            for i in range(count):
                initial, socket, goal_tf, goal = nist_demo(rng)
                save_nist_npz(tmp_path / "nist" / connector / split / f"{i}.npz", initial, socket, goal_tf)
                if split == "train":
                    task = f"insert the {connector} connector into its socket"
                    truth.append((task, initial.astype(np.float32), goal))
    root = tmp_path / "out"

    summary = convert_nist(tmp_path / "nist", "local/nist", root, ConversionOptions(split="train"))

    assert (summary.demos_read, summary.episodes, summary.frames) == (4, 4, 8)
    dataset = LeRobotDataset("local/nist", root=root)
    assert dataset.meta.features[SCENE_KEY]["shape"] == (1024, 3)
    assert sorted(dataset.meta.tasks.index) == sorted({task for task, _, _ in truth})
    _check_goals(dataset, truth)
    card, _ = read_card_info(root)
    assert card.details["source units"].startswith("metres: 4 demos") and "detected" in card.details["source units"]


def test_millimetre_teach_data_is_read_with_open3d_and_scaled(tmp_path):
    rng = np.random.default_rng(1)
    truth = []
    for i in range(2):
        initial, socket, goal_tf, goal = nist_demo(rng, scale=1000.0)  # clouds and translation in mm
        save_nist_teach(tmp_path / "ssd" / f"demo_{i}", initial, socket, goal_tf)
        truth.append(("insert the ssd connector into its socket", (initial * 1e-3).astype(np.float32), goal * 1e-3))
    root = tmp_path / "out"

    summary = convert_nist(tmp_path / "ssd", "local/ssd", root, ConversionOptions())

    dataset = LeRobotDataset("local/ssd", root=root)
    _check_goals(dataset, truth)
    assert "millimetres: 2 demos" in summary.notes[-1]
    readme = (root / "README.md").read_text()
    assert "millimetres: 2 demos (detected from cloud extent)" in readme and "metres" in readme


def test_units_flag_overrides_detection(tmp_path):
    initial, socket, goal_tf, goal = nist_demo(np.random.default_rng(2), scale=1000.0)
    save_nist_npz(tmp_path / "waterproof" / "0.npz", initial, socket, goal_tf)
    save_nist_npz(tmp_path / "waterproof" / "1.npz", initial, socket, goal_tf)
    root = tmp_path / "out"
    convert_nist(tmp_path / "waterproof", "local/mm", root, ConversionOptions(), units="mm")
    item = LeRobotDataset("local/mm", root=root)[0]
    in_metres = (initial.astype(np.float32).astype(np.float64) * 1e-3).astype(np.float32)  # as the .npz stores it
    rows = row_indices(item[OBJECT_KEY].numpy(), in_metres)
    np.testing.assert_allclose(item[ACTION_KEY].numpy(), goal[rows] * 1e-3, atol=2e-6)
    assert "(given by --units)" in read_card_info(root)[0].details["source units"]


def test_seeded_split_reproduces_16_of_20_for_training(tmp_path):
    connector = tmp_path / "waterproof"
    connector.mkdir()
    for i in range(20):
        (connector / f"demo_{i}.npz").write_bytes(b"")  # only names matter to the split
    train = split_demos(connector, "train", seed=0, holdout_fraction=0.2)
    val = split_demos(connector, "val", seed=0, holdout_fraction=0.2)
    assert (len(train), len(val)) == (16, 4)
    assert set(train).isdisjoint(val) and set(train) | set(val) == set(split_demos(connector, "all", 0, 0.2))
    assert split_demos(connector, "test", seed=0, holdout_fraction=0.2) == val
    assert split_demos(connector, "val", seed=0, holdout_fraction=0.2) == val, "same seed, same split"
    assert any(split_demos(connector, "val", seed=s, holdout_fraction=0.2) != val for s in range(1, 4))


@pytest.mark.parametrize(
    ("name", "break_transform"),
    [
        ("scaled", lambda t: t @ np.diag([1.02, 1.0, 1.0, 1.0])),
        ("reflection", lambda t: t @ np.diag([1.0, 1.0, -1.0, 1.0])),
        ("sheared", lambda t: t + np.pad([[0.0, 0.05, 0.0]], ((0, 3), (0, 1)))),
    ],
)
def test_non_rigid_goal_tf_is_rejected_by_name(tmp_path, name, break_transform):
    rng = np.random.default_rng(3)
    for i in range(2):
        initial, socket, goal_tf, _ = nist_demo(rng)
        save_nist_npz(tmp_path / "dsub25" / f"{i}.npz", initial, socket, break_transform(goal_tf) if i else goal_tf)
    root = tmp_path / "out"
    with pytest.raises(PointCloudError, match=r"1\.npz: field 'goal_tf': not a rigid transform"):
        convert_nist(tmp_path / "dsub25", "local/x", root, ConversionOptions())
    assert not root.exists() and leftovers(root) == []


def test_unreadable_ply_names_the_file(tmp_path):
    rng = np.random.default_rng(4)
    for i in range(2):
        initial, socket, goal_tf, _ = nist_demo(rng, scale=1000.0)
        save_nist_teach(tmp_path / "ssd" / f"demo_{i}", initial, socket, goal_tf)
    (tmp_path / "ssd" / "demo_1" / "anchor.ply").write_text("not a ply file")
    with pytest.raises(DemoError, match=r"demo_1: field 'anchor.ply' is empty or not a readable"):
        convert_nist(tmp_path / "ssd", "local/x", tmp_path / "out", ConversionOptions())
    summary = convert_nist(tmp_path / "ssd", "local/x", tmp_path / "out", ConversionOptions(skip_invalid=True))
    assert summary.episodes == 1 and Path(summary.skipped[0].source).name == "demo_1"
