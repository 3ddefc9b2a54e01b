"""The shared dataset writer: LeRobot reads what it writes, and failures never leave partial output."""

import json

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter, read_card_info
from lerobot_taxdpd.data.scaling import SCALE_FILE, median_object_radius
from lerobot_taxdpd.data.schema import (
    ACTION_KEY,
    GOAL_TRANSFORM_KEY,
    OBJECT_KEY,
    goal_prediction_features,
    placement_frame,
)
from lerobot_taxdpd.data.validation import PointCloudError

CARD = DatasetCardInfo(source="unit test", source_license="apache-2.0", command="pytest")


def frame(rng, shift=0.1):
    obj = rng.normal(size=(16, 3)).astype(np.float32)
    transform = np.eye(4)
    transform[:3, 3] = shift
    return placement_frame(obj, rng.normal(size=(32, 3)), obj + shift, transform, source="test")


def write(root, episodes=2, **kwargs):
    rng = np.random.default_rng(0)
    features = goal_prediction_features(16, 32, with_transform=True)
    with DatasetWriter("local/test", root, features, fps=10, card=CARD, **kwargs) as writer:
        for _ in range(episodes):
            writer.add_episode([frame(rng), frame(rng)], "place it")
        writer.skip("demo_9.npz", "field 'action' contains NaN")
    return writer


def test_written_dataset_loads_with_lerobot_and_carries_a_card(tmp_path):
    root = tmp_path / "ds"
    write(root)
    dataset = LeRobotDataset("local/test", root=root)
    assert len(dataset) == 4 and dataset.meta.total_episodes == 2
    item = dataset[0]
    assert tuple(item[OBJECT_KEY].shape) == (16, 3) and tuple(item[GOAL_TRANSFORM_KEY].shape) == (4, 4)
    np.testing.assert_allclose(item[ACTION_KEY].numpy(), item[OBJECT_KEY].numpy() + 0.1, atol=1e-6)
    card = (root / "README.md").read_text()
    assert "unit test" in card and "demo_9.npz" in card and "(16, 3)" in card
    _, skipped = read_card_info(root)
    assert skipped[0].source == "demo_9.npz"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no partial folder left


def test_the_writer_records_the_median_object_radius_that_a_scan_of_the_data_finds(tmp_path):
    root = tmp_path / "ds"
    write(root, episodes=3)
    recorded = json.loads((root / SCALE_FILE).read_text())
    assert recorded["frames"] == 6 and recorded["field"] == OBJECT_KEY
    meta = LeRobotDatasetMetadata("local/test", root=root)  # LeRobot loads the metadata folder beside it
    assert meta.total_frames == 6
    (root / SCALE_FILE).unlink()  # a dataset made elsewhere: its parquet files are scanned
    assert median_object_radius(root) == recorded["median_object_radius"]


def test_error_mid_conversion_leaves_nothing_behind(tmp_path):
    root = tmp_path / "ds"
    rng = np.random.default_rng(0)
    with pytest.raises(RuntimeError, match="boom"):
        with DatasetWriter(
            "local/test", root, goal_prediction_features(16, 32, with_transform=True), fps=10, card=CARD
        ) as w:
            w.add_episode([frame(rng), frame(rng)], "place it")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_existing_output_is_refused_and_replaced_only_when_complete(tmp_path):
    root = tmp_path / "ds"
    write(root, episodes=1)
    with pytest.raises(FileExistsError, match="already exists"):
        write(root)
    before = json.loads((root / "meta" / "info.json").read_text())
    with pytest.raises(RuntimeError):
        with DatasetWriter(
            "local/test", root, goal_prediction_features(16, 32, with_transform=True), fps=10, card=CARD, overwrite=True
        ):
            raise RuntimeError("interrupted")
    assert json.loads((root / "meta" / "info.json").read_text()) == before  # the earlier dataset is intact
    write(root, episodes=3, overwrite=True)
    assert LeRobotDataset("local/test", root=root).meta.total_episodes == 3


def test_bad_episodes_are_rejected_before_anything_is_buffered(tmp_path):
    rng = np.random.default_rng(0)
    features = goal_prediction_features(16, 32, with_transform=True)
    with DatasetWriter("local/test", tmp_path / "ds", features, fps=10, card=CARD) as writer:
        with pytest.raises(ValueError, match="at least 2 frames"):
            writer.add_episode([frame(rng)], "place it")
        wrong = frame(rng)
        wrong[OBJECT_KEY] = np.zeros((15, 3), dtype=np.float32)
        with pytest.raises(ValueError):
            writer.add_episode([frame(rng), wrong], "place it")
        writer.add_episode([frame(rng), frame(rng)], "place it")
    assert LeRobotDataset("local/test", root=tmp_path / "ds").meta.total_frames == 2


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda o, g, t: (o * np.nan, g, t), "field 'observation.pointcloud.object': contains"),
        (lambda o, g, t: (o, g[:-1], t), "shapes"),
        (lambda o, g, t: (o, g, t * 2), "not a rigid transform"),
        (lambda o, g, t: (o, g + 1.0, t), "does not map"),
        (lambda o, g, t: (o[:2], g[:2], t), "at least 3 points"),
    ],
)
def test_placement_frame_names_the_file_and_field(mutate, message):
    rng = np.random.default_rng(0)
    obj = rng.normal(size=(16, 3))
    transform = np.eye(4)
    obj, goal, transform = mutate(obj, obj.copy(), transform)
    with pytest.raises(PointCloudError, match=message) as error:
        placement_frame(obj, rng.normal(size=(8, 3)), goal, transform, source="demo_3.npz")
    assert "demo_3.npz" in str(error.value)
