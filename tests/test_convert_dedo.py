"""DEDO converter: goal demos (goal = start + flow, no pickle loaded) and zarr rollouts (padding never leaks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from conftest import TINY_GC_DP3, run_cli
from convert_fixtures import leftovers, row_indices
from datasets_conv.dedo import convert_dedo_goals, convert_dedo_rollouts
from datasets_conv.pipeline import ConversionOptions
from datasets_conv.raw_io import DemoError
from datasets_conv.samples import dedo_goal_demo, save_dedo_goal_demo, write_dedo_rollouts
from lerobot_taxdpd.data.dataset_writer import read_card_info
from lerobot_taxdpd.data.schema import (
    ACTION_KEY,
    DONE_KEY,
    GOAL_CLOUD_KEY,
    GOAL_TRANSFORM_KEY,
    OBJECT_KEY,
    SCENE_KEY,
    STATE_KEY,
    SUCCESS_KEY,
)
from lerobot_taxdpd.data.validation import PointCloudError


class _TouchOnUnpickle:
    """Unpickling this creates a file: proof that a converter loaded pickled data."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def _goal_dataset(tmp_path: Path, splits=(("train_tax3d", 3), ("val_ood_tax3d", 2))) -> tuple[Path, dict]:
    rng = np.random.default_rng(0)
    base = tmp_path / "cloth=multi-random anchor=single-random hole=single"
    demos = {}
    for folder, count in splits:
        for i in range(count):
            demo = dedo_goal_demo(rng)
            demos[f"{folder}/demo_{i}.npz"] = demo
            save_dedo_goal_demo(base / folder / f"demo_{i}.npz", demo)
    return base, demos


def test_goal_demos_give_start_plus_flow_with_kept_rows(tmp_path):
    base, demos = _goal_dataset(tmp_path)
    root = tmp_path / "goals"

    summary = convert_dedo_goals(base, "local/cloth_goals", root, ConversionOptions(split="test"))

    assert (summary.demos_read, summary.episodes, summary.frames) == (2, 2, 4)
    dataset = LeRobotDataset("local/cloth_goals", root=root)
    assert GOAL_TRANSFORM_KEY not in dataset.meta.features, "cloth is not rigid: no T*"
    assert dataset.meta.features[OBJECT_KEY]["shape"] == (512, 3) == dataset.meta.features[SCENE_KEY]["shape"]
    for i in range(len(dataset)):
        item = dataset[i]
        demo = demos[f"val_ood_tax3d/demo_{int(item['episode_index'])}.npz"]
        rows = row_indices(item[OBJECT_KEY].numpy(), demo["action_pc"])
        assert len(set(rows)) == 512
        np.testing.assert_allclose(item[ACTION_KEY].numpy(), demo["action_pc"][rows] + demo["flow"][rows], atol=1e-6)
        row_indices(item[SCENE_KEY].numpy(), demo["anchor_pc"])
        assert item["task"] == "hang the cloth on a hanger"


def test_goal_demos_never_unpickle_their_dict_fields(tmp_path):
    marker = tmp_path / "unpickled"
    base, demos = _goal_dataset(tmp_path, splits=(("train_tax3d", 2),))
    demo = demos["train_tax3d/demo_0.npz"]
    demo["deform_data"] = np.array({"payload": _TouchOnUnpickle(marker)}, dtype=object)
    save_dedo_goal_demo(base / "train_tax3d" / "demo_0.npz", demo)

    convert_dedo_goals(base, "local/safe", tmp_path / "out", ConversionOptions(split="train"))

    assert not marker.exists()


def test_goal_split_folder_missing_is_refused(tmp_path):
    base, _ = _goal_dataset(tmp_path)
    with pytest.raises(DemoError, match="val_tax3d"):
        convert_dedo_goals(base, "local/x", tmp_path / "out", ConversionOptions(split="val"))


def test_goal_demo_with_flow_of_other_length_is_rejected(tmp_path):
    base, demos = _goal_dataset(tmp_path, splits=(("train_tax3d", 2),))
    demo = demos["train_tax3d/demo_1.npz"]
    demo["flow"] = demo["flow"][:-4]
    save_dedo_goal_demo(base / "train_tax3d" / "demo_1.npz", demo)
    root = tmp_path / "out"
    with pytest.raises(PointCloudError, match=r"demo_1\.npz.*'action_pc'.*'flow'"):
        convert_dedo_goals(base, "local/x", root, ConversionOptions())
    assert not root.exists() and leftovers(root) == []


def test_rollouts_become_time_series_without_padding(tmp_path):
    base = tmp_path / "cloth"
    raw = write_dedo_rollouts(base / "train.zarr", np.random.default_rng(1), [3, 4, 2])
    vertices = int(raw["cloth"][0, 0])
    root = tmp_path / "rollouts"

    summary = convert_dedo_rollouts(base, "local/cloth_rollouts", root, ConversionOptions(split="train"), fps=10)

    assert (summary.demos_read, summary.episodes, summary.frames) == (3, 3, 9)
    dataset = LeRobotDataset("local/cloth_rollouts", root=root)
    assert list(dataset.meta.episodes["length"]) == [3, 4, 2]
    assert dataset.meta.features[GOAL_CLOUD_KEY]["shape"] == (512, 3)
    rows_by_episode: dict[int, np.ndarray] = {}
    for t in range(len(dataset)):
        item = dataset[t]
        cloth = item[OBJECT_KEY].numpy()
        assert not np.any(np.all(cloth == 0.0, axis=1)), "a zero-padded vertex leaked into the cloth"
        rows = row_indices(cloth, raw["action_pcd"][t, :vertices])
        assert rows_by_episode.setdefault(int(item["episode_index"]), rows).tolist() == rows.tolist()
        np.testing.assert_array_equal(item[GOAL_CLOUD_KEY].numpy(), raw["ground_truth"][t, rows])
        row_indices(item[SCENE_KEY].numpy(), raw["anchor_pcd"][t])
        np.testing.assert_array_equal(item[STATE_KEY].numpy(), raw["state"][t])
        np.testing.assert_array_equal(item[ACTION_KEY].numpy(), raw["action"][t])
        last = int(item["frame_index"]) == dataset.meta.episodes["length"][int(item["episode_index"])] - 1
        assert bool(item[DONE_KEY]) == last and not bool(item[SUCCESS_KEY])
    card, _ = read_card_info(root)
    assert "unknown" in card.details["next.success"]
    run_cli(
        "lerobot-train",
        *TINY_GC_DP3,
        "--dataset.repo_id=local/cloth_rollouts",
        f"--dataset.root={root}",
        "--policy.push_to_hub=false",
        "--steps=2",
        "--batch_size=2",
        "--num_workers=0",
        f"--output_dir={tmp_path / 'train'}",
    )
    assert (tmp_path / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file()


def test_rollouts_marked_successful_on_request(tmp_path):
    write_dedo_rollouts(tmp_path / "train.zarr", np.random.default_rng(2), [2, 3])
    root = tmp_path / "out"
    convert_dedo_rollouts(tmp_path / "train.zarr", "local/ok", root, ConversionOptions(), successful=True)
    dataset = LeRobotDataset("local/ok", root=root)
    assert [bool(dataset[i][SUCCESS_KEY]) for i in range(len(dataset))] == [False, True, False, False, True]


def test_bad_rollout_episode_is_named_and_skippable(tmp_path):
    rng = np.random.default_rng(3)
    state = rng.normal(size=(9, 12)).astype(np.float32)
    state[4, 2] = np.nan  # inside episode 1 (steps 3..6)
    write_dedo_rollouts(tmp_path / "train.zarr", rng, [3, 4, 2], state=state)
    with pytest.raises(PointCloudError, match=r"episode 1\].*'data/state'.*NaN"):
        convert_dedo_rollouts(tmp_path, "local/x", tmp_path / "out", ConversionOptions(split="train"))

    summary = convert_dedo_rollouts(tmp_path, "local/x", tmp_path / "out", ConversionOptions(skip_invalid=True))
    assert summary.episodes == 2 and [s.source for s in summary.skipped] == [f"{tmp_path / 'train.zarr'}[episode 1]"]


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ({"cloth": np.full((7, 1), 700, dtype=np.int64)}, "data/cloth"),  # more vertices than the padded width
        ({"cloth": np.full((7, 1), 100, dtype=np.int64)}, "data/cloth"),  # fewer than the points asked for
    ],
)
def test_bad_true_vertex_count_is_rejected(tmp_path, override, field):
    write_dedo_rollouts(tmp_path / "train.zarr", np.random.default_rng(4), [3, 4], **override)
    with pytest.raises(DemoError, match=field):
        convert_dedo_rollouts(tmp_path / "train.zarr", "local/x", tmp_path / "out", ConversionOptions())


def test_broken_episode_ends_and_missing_fields_name_the_store(tmp_path):
    import zarr

    store = tmp_path / "train.zarr"
    write_dedo_rollouts(store, np.random.default_rng(5), [3, 4])
    zarr.open_group(str(store), mode="a")["meta/episode_ends"][:] = [4, 3]
    with pytest.raises(DemoError, match="meta/episode_ends"):
        convert_dedo_rollouts(store, "local/x", tmp_path / "out", ConversionOptions())
    del zarr.open_group(str(store), mode="a")["data/ground_truth"]
    with pytest.raises(DemoError, match="missing field 'data/ground_truth'"):
        convert_dedo_rollouts(store, "local/x", tmp_path / "out", ConversionOptions())
