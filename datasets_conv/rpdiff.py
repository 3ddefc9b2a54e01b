"""RPDiff relational-placement demos (`demo_aug_<i>.npz`, per demo or chunked) -> goal-prediction dataset.

Layout read (RPDiff's `data/task_demos/<task>/<task_type>/`):

    <task>/<task_type>/demo_aug_<i>.npz            one demo per file
    <task>_chunked/<task_type>/<k>/demo_aug_<j>.npz  chunked: keys "0".."9" each hold a whole demo dict
    <task>/<task_type>/split_info/{train_split,train_val_split,test_split}.txt

Each demo holds dicts in 0-d object arrays, so the files are unpickled: convert only files you trust.
The child (object) start cloud becomes `observation.pointcloud.object`, the parent start cloud the scene,
T* = final_child_pose @ inv(start_child_pose) the `goal.transform`, and the goal is T* applied to the
sampled start points (so `action` == T* `observation.pointcloud.object` to float precision). The raw final
child cloud must agree with T* applied to the raw start child cloud; otherwise the demo is rejected.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from datasets_conv.pipeline import (
    ConversionOptions,
    ConversionSummary,
    DemoRef,
    card_details,
    sampled_frames,
    write_dataset,
)
from datasets_conv.raw_io import (
    DemoError,
    LayoutError,
    as_cloud,
    dict_entry,
    layout_error,
    natural_key,
    open_npz,
    read_field,
    unwrap_dict,
)
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo
from lerobot_taxdpd.data.schema import DEFAULT_POINT_COUNTS, GOAL_DATASET_FPS, goal_prediction_features
from lerobot_taxdpd.data.validation import check_same_shape
from lerobot_taxdpd.maths.geometry import pose_to_matrix, transform_points

START_PCD = "multi_obj_start_pcd"
FINAL_PCD = "multi_obj_final_pcd"
START_POSE = "multi_obj_start_obj_pose"
FINAL_POSE = "multi_obj_final_obj_pose"
DEMO_GLOB = "demo_aug_*.npz"
SPLIT_FILES = {"train": "train_split.txt", "val": "train_val_split.txt", "test": "test_split.txt"}

#: Largest distance (metres) allowed between the raw final child cloud and T* applied to the start cloud.
POSE_TOLERANCE = 1e-3

#: Point counts for RPDiff tasks outside the paper's table: the largest of the table.
FALLBACK_POINT_COUNTS = (512, 1024)


@dataclass(frozen=True)
class RPDiffTask:
    directory: str
    paper_name: str
    dataset_name: str
    task: str


#: The paper's five RPDiff tasks: RPDiff directory -> paper name, suggested dataset name, task string.
RPDIFF_TASKS: dict[str, RPDiffTask] = {
    t.directory: t
    for t in (
        RPDiffTask("mug_rack_easy_single", "Mug/EasyRack", "rpdiff_mug_easyrack", "hang the mug on the rack"),
        RPDiffTask("mug_rack_med_single", "Mug/MedRack", "rpdiff_mug_medrack", "hang the mug on the rack"),
        RPDiffTask(
            "mug_rack_med_multi", "Mug/Multi-MedRack", "rpdiff_mug_multi_medrack", "hang the mug on one of the racks"
        ),
        RPDiffTask(
            "book_on_bookshelf_double_view_rnd_ori", "Book/Shelf", "rpdiff_book_shelf", "put the book in the bookshelf"
        ),
        RPDiffTask("can_in_cabinet_stack", "Can/Cabinet", "rpdiff_can_cabinet", "place the can in the cabinet"),
    )
}


def _demo_files(directory: Path) -> list[Path]:
    """Demo files directly in `directory` or in its numbered chunk folders, in natural order."""
    chunks = [p for p in directory.iterdir() if p.is_dir() and p.name.isdigit()]
    files = [*directory.glob(DEMO_GLOB), *(f for chunk in chunks for f in chunk.glob(DEMO_GLOB))]
    return sorted(files, key=natural_key)


def find_demo_dir(raw_dir: Path) -> Path:
    """The folder holding the demos: `raw_dir` itself, or its single `task_name_*` sub-folder."""
    if not raw_dir.is_dir():
        raise FileNotFoundError(f"--raw-dir {raw_dir}: no such folder")
    if _demo_files(raw_dir):
        return raw_dir
    task_types = sorted(p for p in raw_dir.glob("task_name_*") if p.is_dir() and _demo_files(p))
    if len(task_types) == 1:
        return task_types[0]
    if task_types:
        names = ", ".join(p.name for p in task_types)
        raise LayoutError(f"{raw_dir}: several task types ({names}); point --raw-dir at one of them")
    raise layout_error(raw_dir, f"no {DEMO_GLOB} files here or in chunk sub-folders", lambda p: bool(_demo_files(p)))


def identify_task(demo_dir: Path) -> tuple[str, RPDiffTask | None]:
    """RPDiff task directory name (from the path) and, for the paper's tasks, its description."""
    for part in (demo_dir, *demo_dir.parents):
        name = part.name.removesuffix("_chunked")
        if name in RPDIFF_TASKS:
            return name, RPDIFF_TASKS[name]
    own = demo_dir.name.removesuffix("_chunked")
    return (demo_dir.parent.name if own.startswith("task_name_") else own), None


def _split_names(demo_dir: Path, split: str) -> set[str] | None:
    if split == "all":
        return None
    path = demo_dir / "split_info" / SPLIT_FILES[split]
    if not path.is_file():
        raise DemoError(f"{path}: split file not found; use --split all to convert every demo")
    return {line.strip() for line in path.read_text().splitlines() if line.strip()}


def list_demos(demo_dir: Path, split: str) -> tuple[list[DemoRef], list[str]]:
    """Every demo of the split (chunk files expand to one demo per key) and notes for the summary."""
    files = _demo_files(demo_dir)
    wanted = _split_names(demo_dir, split)
    notes = []
    if wanted is not None:
        found = {f.name for f in files}
        if not wanted & found:
            raise DemoError(f"{demo_dir}: none of the {len(wanted)} files named in the {split} split exist")
        if missing := len(wanted - found):
            notes.append(f"{missing} files named in the {split} split are not in {demo_dir}")
        files = [f for f in files if f.name in wanted]
    demos = []
    for path in files:
        try:
            keys = open_npz(path, allow_pickle=True).files
        except DemoError:
            keys = []  # listed as one demo; reading it reports the error
        if keys and all(k.isdigit() for k in keys):
            demos += [DemoRef(f"{path}[{k}]", path, k) for k in sorted(keys, key=int)]
        else:
            demos.append(DemoRef(str(path), path))
    return demos, notes


def _demo_fields(demo: DemoRef):
    """A getter for the demo's top-level fields, whether it is a whole file or one key of a chunk."""
    archive = open_npz(demo.path, allow_pickle=True)
    if demo.key is None:
        return lambda name: read_field(archive, demo.source, name)
    whole = unwrap_dict(read_field(archive, demo.source, demo.key), demo.source, demo.key)
    return lambda name: read_field(whole, demo.source, name)


def pose_matrix(value, source: str, field: str) -> np.ndarray:
    """4x4 pose from [x, y, z, qx, qy, qz, qw], or from the first of a list of such 7-lists."""
    try:
        pose = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DemoError(f"{source}: field '{field}' is not a pose or list of poses ({exc})") from exc
    if pose.ndim == 2 and pose.shape[0] >= 1 and pose.shape[1] == 7:
        pose = pose[0]
    if pose.shape != (7,):
        raise DemoError(
            f"{source}: field '{field}' should be [x, y, z, qx, qy, qz, qw] or a list of them, got shape {pose.shape}"
        )
    if not np.isfinite(pose).all():
        raise DemoError(f"{source}: field '{field}' contains NaN or infinite values")
    norm = float(np.linalg.norm(pose[3:]))
    if abs(norm - 1.0) > 1e-3:
        raise DemoError(f"{source}: field '{field}' quaternion (xyzw) has norm {norm:.4g}, expected a unit quaternion")
    return pose_to_matrix(pose[:3], pose[3:])


def goal_transform(get, source: str) -> np.ndarray:
    """T* = final_child_pose @ inv(start_child_pose)."""
    poses = {}
    for field in (START_POSE, FINAL_POSE):
        child = dict_entry(unwrap_dict(get(field), source, field), source, field, "child")
        poses[field] = pose_matrix(child, source, f"{field}['child']")
    return poses[FINAL_POSE] @ np.linalg.inv(poses[START_POSE])


def demo_episode(demo: DemoRef, options: ConversionOptions, counts: tuple[int, int], task: str):
    """All frames of one demo: independent samplings of the same start/goal/scene clouds."""
    get = _demo_fields(demo)
    num_object, num_scene = counts
    start = unwrap_dict(get(START_PCD), demo.source, START_PCD)
    final = unwrap_dict(get(FINAL_PCD), demo.source, FINAL_PCD)
    child_field, final_field = f"{START_PCD}['child']", f"{FINAL_PCD}['child']"
    child = as_cloud(
        dict_entry(start, demo.source, START_PCD, "child"), demo.source, child_field, min_points=num_object
    )
    final_child = as_cloud(dict_entry(final, demo.source, FINAL_PCD, "child"), demo.source, final_field, min_points=3)
    parent = as_cloud(
        dict_entry(start, demo.source, START_PCD, "parent"), demo.source, f"{START_PCD}['parent']", min_points=num_scene
    )
    check_same_shape(child, final_child, f"{demo.source}: field '{child_field}'", f"field '{final_field}'")
    transform = goal_transform(get, demo.source)
    error = float(np.abs(transform_points(transform, child) - final_child).max())
    if error > POSE_TOLERANCE:
        raise DemoError(
            f"{demo.source}: field '{final_field}' is not T* (from the child poses) applied to '{child_field}' "
            f"(max error {error:.3g} m > {POSE_TOLERANCE:g} m)"
        )
    return sampled_frames(demo.source, child, parent, counts, options, transform=transform), task


def convert_rpdiff(raw_dir: Path, repo_id: str, root: Path, options: ConversionOptions) -> ConversionSummary:
    """Convert one RPDiff task folder into a LeRobot goal-prediction dataset at `root`."""
    demo_dir = find_demo_dir(Path(raw_dir))
    name, known = identify_task(demo_dir)
    counts = options.point_counts(DEFAULT_POINT_COUNTS.get(name, FALLBACK_POINT_COUNTS))
    task = options.task or (known.task if known else f"place the object as in RPDiff task {name}")
    demos, notes = list_demos(demo_dir, options.split)
    if known is None and not (options.object_cloud_size and options.scene_cloud_size):
        notes.append(f"{name} is not one of the paper's tasks; point counts not given default to {counts}")
    details = {"RPDiff task": name, **card_details(options, *counts)}
    if known:
        details["paper task"] = known.paper_name
    card = DatasetCardInfo(
        source=f"RPDiff relational-placement demos (Simeonov et al., CoRL 2023), task `{name}`",
        source_license="MIT (RPDiff); mug clouds are rendered from ShapeNet meshes, whose terms of use apply",
        units="metres, world frame (as in the source)",
        command=options.command,
        description=(
            f"TAX-DPD goal-prediction dataset converted from RPDiff's `{name}` demos. Each episode is one demo; "
            "its frames are independent farthest-point samplings of the same demo. `action` is the goal cloud of "
            "the object (row i corresponds to row i of `observation.pointcloud.object`) and `goal.transform` the "
            "rigid T* with action = T* object."
        ),
        hub_license=options.hub_license or "other",
        tags=["rpdiff", name],
        details=details,
    )
    return write_dataset(
        demos,
        lambda demo: demo_episode(demo, options, counts, task),
        source_name="rpdiff",
        repo_id=repo_id,
        root=Path(root),
        features=goal_prediction_features(*counts, with_transform=True),
        fps=GOAL_DATASET_FPS,
        card=card,
        options=options,
        notes=notes,
    )
