"""RPDiff converter: both pose layouts, the chunked variant, splits, the paper's tasks and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from convert_fixtures import leftovers, row_indices
from datasets_conv.pipeline import ConversionOptions
from datasets_conv.raw_io import DemoError
from datasets_conv.rpdiff import RPDIFF_TASKS, convert_rpdiff, find_demo_dir, identify_task
from datasets_conv.samples import rpdiff_demo, save_rpdiff_chunk, save_rpdiff_demo, write_split_info
from lerobot_taxdpd.data.dataset_writer import read_card_info
from lerobot_taxdpd.data.schema import ACTION_KEY, DEFAULT_POINT_COUNTS, GOAL_TRANSFORM_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.data.validation import PointCloudError

DOCS = Path(__file__).resolve().parents[1] / "docs" / "converters.md"


def _task_dir(tmp_path: Path, task: str = "mug_rack_easy_single", task_type: str = "task_name_mug_on_rack") -> Path:
    return tmp_path / "task_demos" / task / task_type


def _write_demos(demo_dir: Path, count: int, seed: int = 0) -> dict[str, tuple[dict, np.ndarray]]:
    rng = np.random.default_rng(seed)
    demos = {}
    for i in range(count):
        demo, transform = rpdiff_demo(rng, nested_pose=i % 2 == 1)  # both pose layouts
        save_rpdiff_demo(demo_dir / f"demo_aug_{i}.npz", demo)
        demos[f"demo_aug_{i}.npz"] = (demo, transform)
    return demos


def _episodes(dataset: LeRobotDataset) -> dict[int, list[dict]]:
    episodes: dict[int, list[dict]] = {}
    for i in range(len(dataset)):
        item = dataset[i]
        episodes.setdefault(int(item["episode_index"]), []).append(item)
    return episodes


def test_per_demo_files_become_episodes_lerobot_loads(tmp_path):
    demo_dir = _task_dir(tmp_path)
    demos = _write_demos(demo_dir, 4)
    names = list(demos)
    write_split_info(demo_dir, {"train": names[:3], "val": names[3:], "test": []})
    root = tmp_path / "out"

    summary = convert_rpdiff(demo_dir.parent, "local/rpdiff", root, ConversionOptions(split="train"))

    assert (summary.demos_read, summary.episodes, summary.frames, summary.skipped) == (3, 3, 6, [])
    dataset = LeRobotDataset("local/rpdiff", root=root)
    assert dataset.meta.total_episodes == 3
    assert dataset.meta.features[OBJECT_KEY]["shape"] == (512, 3) == dataset.meta.features[SCENE_KEY]["shape"]
    for index, frames in _episodes(dataset).items():
        demo, true_transform = demos[names[index]]
        assert len(frames) == 2
        assert not np.array_equal(frames[0][OBJECT_KEY], frames[1][OBJECT_KEY]), "frames should be distinct samplings"
        for item in frames:
            assert item["task"] == "hang the mug on the rack"
            obj, goal = item[OBJECT_KEY].numpy(), item[ACTION_KEY].numpy()
            transform = item[GOAL_TRANSFORM_KEY].numpy().astype(np.float64)
            np.testing.assert_allclose(transform, true_transform, atol=1e-6)
            np.testing.assert_allclose(obj @ transform[:3, :3].T + transform[:3, 3], goal, atol=1e-5)
            raw_rows = row_indices(obj, demo["multi_obj_start_pcd"]["child"])
            assert len(set(raw_rows)) == 512
            np.testing.assert_allclose(goal, demo["multi_obj_final_pcd"]["child"][raw_rows], atol=1e-5)
            row_indices(item[SCENE_KEY].numpy(), demo["multi_obj_start_pcd"]["parent"])
    card, skipped = read_card_info(root)
    assert card.details["paper task"] == "Mug/EasyRack" and skipped == []
    assert leftovers(root) == []


def test_same_seed_gives_same_dataset_and_other_seed_other_samplings(tmp_path):
    demo_dir = _task_dir(tmp_path)
    _write_demos(demo_dir, 2)
    clouds = {}
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        convert_rpdiff(demo_dir, f"local/{name}", tmp_path / name, ConversionOptions(seed=seed))
        clouds[name] = LeRobotDataset(f"local/{name}", root=tmp_path / name)[0][OBJECT_KEY]
    assert np.array_equal(clouds["a"], clouds["b"])
    assert not np.array_equal(clouds["a"], clouds["c"])


def test_chunked_variant_expands_every_key(tmp_path):
    demo_dir = tmp_path / "mug_rack_med_multi_chunked" / "task_name_mug_on_rack_multi"
    rng = np.random.default_rng(3)
    chunks = {k: [rpdiff_demo(rng, nested_pose=j == 0) for j in range(n)] for k, n in ((0, 3), (1, 2))}
    for k, demos in chunks.items():
        save_rpdiff_chunk(demo_dir / str(k) / "demo_aug_0.npz", [d for d, _ in demos])
    root = tmp_path / "out"

    summary = convert_rpdiff(demo_dir, "local/chunked", root, ConversionOptions())

    assert (summary.demos_read, summary.episodes) == (5, 5)
    dataset = LeRobotDataset("local/chunked", root=root)
    assert dataset.meta.features[SCENE_KEY]["shape"] == (1024, 3), "Mug/Multi-MedRack uses 512/1024 points"
    flat = [pair for k in sorted(chunks) for pair in chunks[k]]
    for index, frames in _episodes(dataset).items():
        np.testing.assert_allclose(frames[0][GOAL_TRANSFORM_KEY].numpy(), flat[index][1], atol=1e-6)
        assert frames[0]["task"] == "hang the mug on one of the racks"


@pytest.mark.parametrize("directory", sorted(RPDIFF_TASKS))
def test_paper_tasks_map_to_documented_names_and_point_counts(tmp_path, directory):
    task = RPDIFF_TASKS[directory]
    demo_dir = tmp_path / directory / "task_name_x"
    _write_demos(demo_dir, 1)
    assert identify_task(find_demo_dir(tmp_path / directory)) == (directory, task)
    assert directory in DEFAULT_POINT_COUNTS
    docs = DOCS.read_text()
    assert all(name in docs for name in (directory, task.paper_name, task.dataset_name, task.task))


def test_split_without_split_files_is_refused(tmp_path):
    demo_dir = _task_dir(tmp_path)
    _write_demos(demo_dir, 2)
    with pytest.raises(DemoError, match="split_info.*--split all"):
        convert_rpdiff(demo_dir, "local/x", tmp_path / "out", ConversionOptions(split="test"))


def _corrupt(kind: str, path: Path, demo: dict) -> str:
    """Break one demo file; returns the field the error must name."""
    start, final = demo["multi_obj_start_pcd"], demo["multi_obj_final_pcd"]
    if kind == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        return ".npz"
    if kind == "not_npz":
        path.write_text("this is not a numpy archive\n")
        return ".npz"
    if kind == "missing_key":
        del demo["multi_obj_final_obj_pose"]
        field = "multi_obj_final_obj_pose"
    elif kind == "nan":
        start["child"][5, 1] = np.nan
        field = "multi_obj_start_pcd['child']"
    elif kind == "tiny":
        start["child"] = start["child"][:10]
        final["child"] = final["child"][:10]
        field = "multi_obj_start_pcd['child']"
    elif kind == "empty_scene":
        start["parent"] = np.zeros((0, 3))
        field = "multi_obj_start_pcd['parent']"
    elif kind == "count_mismatch":
        final["child"] = final["child"][:-7]
        field = "multi_obj_final_pcd['child']"
    elif kind == "poses_disagree":
        final["child"] = final["child"] + [0.0, 0.0, 0.05]
        field = "multi_obj_final_pcd['child']"
    save_rpdiff_demo(path, demo)
    return field


BAD_KINDS = ["truncated", "not_npz", "missing_key", "nan", "tiny", "empty_scene", "count_mismatch", "poses_disagree"]


@pytest.mark.parametrize("kind", BAD_KINDS)
def test_bad_demo_stops_with_file_and_field_and_writes_nothing(tmp_path, kind):
    demo_dir = _task_dir(tmp_path)
    demos = _write_demos(demo_dir, 3)
    field = _corrupt(kind, demo_dir / "demo_aug_1.npz", demos["demo_aug_1.npz"][0])
    root = tmp_path / "out"
    with pytest.raises((DemoError, PointCloudError)) as error:
        convert_rpdiff(demo_dir, "local/bad", root, ConversionOptions())
    assert "demo_aug_1.npz" in str(error.value) and field in str(error.value)
    assert not root.exists() and leftovers(root) == []


def test_skip_invalid_converts_the_rest_and_lists_the_skipped(tmp_path):
    demo_dir = _task_dir(tmp_path)
    demos = _write_demos(demo_dir, 4)
    _corrupt("nan", demo_dir / "demo_aug_1.npz", demos["demo_aug_1.npz"][0])
    _corrupt("truncated", demo_dir / "demo_aug_3.npz", demos["demo_aug_3.npz"][0])
    root = tmp_path / "out"

    summary = convert_rpdiff(demo_dir, "local/skip", root, ConversionOptions(skip_invalid=True))

    assert (summary.demos_read, summary.episodes) == (4, 2)
    assert [Path(s.source).name for s in summary.skipped] == ["demo_aug_1.npz", "demo_aug_3.npz"]
    assert "NaN" in summary.skipped[0].reason and "demo_aug_3.npz" in str(summary)
    assert LeRobotDataset("local/skip", root=root).meta.total_episodes == 2
    _, skipped = read_card_info(root)
    readme = (root / "README.md").read_text()
    assert len(skipped) == 2 and "Skipped inputs (2)" in readme and "demo_aug_1.npz" in readme


def test_existing_output_is_refused_and_failed_overwrite_keeps_it(tmp_path):
    demo_dir = _task_dir(tmp_path)
    _write_demos(demo_dir, 2)
    root = tmp_path / "out"
    convert_rpdiff(demo_dir, "local/keep", root, ConversionOptions())
    before = sorted(p.relative_to(root) for p in root.rglob("*"))

    with pytest.raises(FileExistsError, match="already exists"):
        convert_rpdiff(demo_dir, "local/keep", root, ConversionOptions())
    _write_demos(demo_dir, 3, seed=9)
    _corrupt("nan", demo_dir / "demo_aug_2.npz", rpdiff_demo(np.random.default_rng(1))[0])
    with pytest.raises(PointCloudError):
        convert_rpdiff(demo_dir, "local/keep", root, ConversionOptions(overwrite=True))

    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before
    assert LeRobotDataset("local/keep", root=root).meta.total_episodes == 2 and leftovers(root) == []
