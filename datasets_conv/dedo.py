"""DEDO HangProcCloth demos, as generated for TAX3D, -> goal-prediction and cloth-policy datasets.

Two inputs live side by side in one TAX3D cloth dataset folder:

    <dataset>/{train,val,val_ood}_tax3d/demo_<i>.npz   goal demos: action_pc (cloth at start), anchor_pc
                                                       (hangers), flow (final - start); goal = action_pc + flow
    <dataset>/{train,val}.zarr                         policy rollouts (DP3 layout, Blosc zstd): data/{action_pcd,
                                                       anchor_pcd, state, action, cloth, ground_truth},
                                                       meta/episode_ends

`--kind goal` writes the goal-prediction schema (no `goal.transform`: cloth is not rigid); `--kind policy`
writes the `gc_dp3` time series. The rollouts pad the cloth to 625 vertices with zeros; `data/cloth` holds
the true count, and only those rows are sampled. The goal files' dict fields (`deform_data`, `rigid_data`)
are never read, so no pickle is loaded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from datasets_conv.pipeline import (
    ConversionOptions,
    ConversionSummary,
    DemoRef,
    card_details,
    demo_rng,
    sampled_frames,
    sampling_indices,
    write_dataset,
)
from datasets_conv.raw_io import DemoError, as_cloud, as_finite, layout_error, natural_key, open_npz, read_field
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo
from lerobot_taxdpd.data.schema import (
    ACTION_KEY,
    DEFAULT_POINT_COUNTS,
    DONE_KEY,
    GOAL_CLOUD_KEY,
    GOAL_DATASET_FPS,
    OBJECT_KEY,
    SCENE_KEY,
    STATE_KEY,
    SUCCESS_KEY,
    cloth_policy_features,
    goal_prediction_features,
)
from lerobot_taxdpd.data.validation import check_point_cloud, check_same_shape
from lerobot_taxdpd.maths.geometry import farthest_point_indices

DEMO_GLOB = "demo_*.npz"
GOAL_SPLIT_DIRS = {"train": ("train_tax3d", "train"), "val": ("val_tax3d", "val"), "test": ("val_ood_tax3d", "test")}
ROLLOUT_STORES = {"train": ("train.zarr",), "val": ("val.zarr",), "test": ("val_ood.zarr", "test.zarr")}
ROLLOUT_FIELDS = ("action_pcd", "anchor_pcd", "ground_truth", "state", "action", "cloth")
DEFAULT_TASK = "hang the cloth on a hanger"

SOURCE_LICENSE = (
    "DEDO simulator: MIT; the demonstration files carry no licence of their own, "
    "ask their authors before redistributing"
)
UNITS = "DEDO simulation units, world frame as in the source (the scene is scaled, so not metres)"


def _select(raw_dir: Path, split: str, choices: dict[str, tuple[str, ...]], is_input) -> list[Path]:
    """The split's input folders or stores under `raw_dir` (every present one for `all`)."""
    if not raw_dir.is_dir():
        raise FileNotFoundError(f"--raw-dir {raw_dir}: no such folder")
    splits = list(choices) if split == "all" else [split]
    found = []
    for name in splits:
        found += [raw_dir / c for c in choices[name] if is_input(raw_dir / c)][:1]
    if not found and split != "all":
        wanted = " or ".join(choices[split])
        raise DemoError(f"{raw_dir}: no {wanted} for --split {split}")
    return found


# ------------------------------------------------------------------------------------------ goal demos
def list_goal_demos(raw_dir: Path, split: str) -> list[DemoRef]:
    """`demo_*.npz` of a split folder, or of `raw_dir` itself when it holds the demos directly."""
    if any(raw_dir.glob(DEMO_GLOB)):
        if split != "all":
            raise DemoError(f"{raw_dir}: holds the demos directly, without split folders; use --split all")
        folders = [raw_dir]
    else:
        folders = _select(raw_dir, split, GOAL_SPLIT_DIRS, lambda p: p.is_dir() and any(p.glob(DEMO_GLOB)))
        if not folders:
            stores = [p.name for p in raw_dir.glob("*.zarr")]
            hint = f" (found {', '.join(stores)}: use --kind policy)" if stores else ""
            raise layout_error(raw_dir, f"no {DEMO_GLOB} files or split folders{hint}", _holds_goal_demos)
    files = [f for folder in folders for f in sorted(folder.glob(DEMO_GLOB), key=natural_key)]
    return [DemoRef(str(f), f) for f in files]


def _holds_goal_demos(folder: Path) -> bool:
    """`folder` is a --raw-dir of goal demos: demo files, or split folders of them."""
    splits = [folder / name for names in GOAL_SPLIT_DIRS.values() for name in names]
    return any(folder.glob(DEMO_GLOB)) or any(split.is_dir() and any(split.glob(DEMO_GLOB)) for split in splits)


def goal_episode(demo: DemoRef, options: ConversionOptions, counts: tuple[int, int], task: str):
    """Independent samplings of one goal demo; cloth start and goal share indices."""
    archive = open_npz(demo.path)
    num_object, num_scene = counts
    cloth = as_cloud(read_field(archive, demo.source, "action_pc"), demo.source, "action_pc", min_points=num_object)
    flow = as_cloud(read_field(archive, demo.source, "flow"), demo.source, "flow", min_points=num_object)
    check_same_shape(cloth, flow, f"{demo.source}: field 'action_pc'", "field 'flow'")
    hangers = as_cloud(read_field(archive, demo.source, "anchor_pc"), demo.source, "anchor_pc", min_points=num_scene)
    goal = cloth + flow
    return sampled_frames(demo.source, cloth, hangers, counts, options, goal_points=goal), task


# -------------------------------------------------------------------------------------- policy rollouts
class RolloutStore:
    """One DP3-layout zarr store of cloth rollouts, checked once when opened."""

    def __init__(self, path: Path) -> None:
        import zarr

        self.path = path
        try:
            self.group = zarr.open_group(str(path), mode="r")
        except (ValueError, OSError, KeyError) as exc:
            raise DemoError(f"{path}: not a readable zarr group ({type(exc).__name__}: {exc})") from exc
        self.ends = self._read("meta", "episode_ends").astype(np.int64).reshape(-1)
        self.arrays = {name: self._array("data", name) for name in ROLLOUT_FIELDS}
        total = self.arrays["state"].shape[0]
        for name, array in self.arrays.items():
            if array.shape[0] != total:
                raise DemoError(f"{path}: field 'data/{name}' has {array.shape[0]} steps, 'data/state' has {total}")
        if self.ends.size == 0 or np.any(np.diff(self.ends) <= 0) or self.ends[0] <= 0 or self.ends[-1] != total:
            raise DemoError(
                f"{path}: field 'meta/episode_ends' must be increasing cumulative step counts ending at {total}, "
                f"got {self.ends.tolist()[:8]}"
            )
        self.state_dim = self.arrays["state"].shape[1]
        self.action_dim = self.arrays["action"].shape[1]

    def _array(self, group: str, name: str):
        try:
            return self.group[f"{group}/{name}"]
        except KeyError as exc:
            present = ", ".join(sorted(self.group[group].array_keys())) if group in self.group else "none"
            raise DemoError(f"{self.path}: missing field '{group}/{name}' (found in {group}/: {present})") from exc

    def _read(self, group: str, name: str, rows: slice = slice(None)) -> np.ndarray:
        try:
            return np.asarray(self._array(group, name)[rows])
        except (ValueError, RuntimeError, OSError) as exc:
            raise DemoError(f"{self.path}: field '{group}/{name}' cannot be read ({exc})") from exc

    def episode_refs(self) -> list[DemoRef]:
        return [DemoRef(f"{self.path}[episode {i}]", self.path, str(i)) for i in range(len(self.ends))]

    def episode(self, index: int) -> tuple[str, dict[str, np.ndarray]]:
        """`(source, {field: rows of the episode})`."""
        start = 0 if index == 0 else int(self.ends[index - 1])
        rows = slice(start, int(self.ends[index]))
        return f"{self.path}[episode {index}]", {name: self._read("data", name, rows) for name in ROLLOUT_FIELDS}


def _is_store(path: Path) -> bool:
    return (path / ".zgroup").is_file()


def list_rollouts(raw_dir: Path, split: str) -> tuple[list[DemoRef], dict[Path, RolloutStore]]:
    """Episodes of the split's zarr stores. A store that fails to open stays in the list as one demo that
    reports its error (so --skip-invalid can pass over it); if none opens, the first error is raised."""
    if _is_store(raw_dir) and split != "all":
        raise DemoError(f"{raw_dir}: is one zarr store, without splits; use --split all")
    paths = [raw_dir] if _is_store(raw_dir) else _select(raw_dir, split, ROLLOUT_STORES, _is_store)
    if not paths:
        raise DemoError(f"{raw_dir}: no zarr store (.zgroup) of rollouts for --split {split}")
    demos, stores, errors = [], {}, []
    for path in paths:
        try:
            stores[path] = RolloutStore(path)
            demos += stores[path].episode_refs()
        except DemoError as exc:
            errors.append(exc)
            demos.append(DemoRef(str(path), path))
    if not stores:
        raise errors[0]
    return demos, stores


def rollout_episode(
    demo: DemoRef,
    stores: dict[Path, RolloutStore],
    options: ConversionOptions,
    counts: tuple[int, int],
    dims: tuple[int, int],
    task: str,
    successful: bool,
):
    """One rollout as a time series; the cloth is sampled once per episode so vertex rows stay the same."""
    store = stores.get(demo.path) or RolloutStore(demo.path)
    source, data = store.episode(int(demo.key))
    num_object, num_scene = counts
    steps = data["state"].shape[0]
    if steps < 2:
        raise DemoError(f"{source}: has {steps} step; an episode needs at least 2 (LeRobot 0.4.4)")
    if (store.state_dim, store.action_dim) != dims:
        raise DemoError(f"{source}: state/action sizes {store.state_dim}/{store.action_dim} differ from {dims}")
    counts_field = np.asarray(data["cloth"]).reshape(steps, -1)[:, 0]
    vertices = int(counts_field[0])
    padded = data["action_pcd"].shape[1]
    if np.any(counts_field != vertices) or not num_object <= vertices <= padded:
        raise DemoError(
            f"{source}: field 'data/cloth' must hold one true vertex count per episode between "
            f"{num_object} (--object-cloud-size) and {padded}, got {np.unique(counts_field).tolist()[:5]}"
        )
    cloth = data["action_pcd"][:, :vertices].astype(np.float64)
    goal = data["ground_truth"][:, :vertices].astype(np.float64)
    hangers = data["anchor_pcd"].astype(np.float64)
    for name, clouds in (("action_pcd", cloth), ("ground_truth", goal), ("anchor_pcd", hangers)):
        check_point_cloud(clouds, f"{source}: field 'data/{name}'", min_points=3, batched=True)
    if hangers.shape[1] < num_scene:
        raise DemoError(f"{source}: field 'data/anchor_pcd' has {hangers.shape[1]} points, fewer than {num_scene}")
    state = as_finite(data["state"], source, "data/state", (steps, dims[0]))
    action = as_finite(data["action"], source, "data/action", (steps, dims[1]))
    cloth_idx = sampling_indices(cloth[0], num_object, 1, demo_rng(options.seed, source))[0]
    frames = []
    for t in range(steps):
        last = t == steps - 1
        frames.append(
            {
                OBJECT_KEY: cloth[t, cloth_idx].astype(np.float32),
                SCENE_KEY: hangers[t, farthest_point_indices(hangers[t], num_scene)].astype(np.float32),
                GOAL_CLOUD_KEY: goal[t, cloth_idx].astype(np.float32),
                STATE_KEY: state[t].astype(np.float32),
                ACTION_KEY: action[t].astype(np.float32),
                DONE_KEY: np.array([last]),
                SUCCESS_KEY: np.array([last and successful]),
            }
        )
    return frames, task


# -------------------------------------------------------------------------------------------- entry
def _card(options: ConversionOptions, kind: str, description: str, details: dict[str, str]) -> DatasetCardInfo:
    return DatasetCardInfo(
        source=f"DEDO HangProcCloth cloth-hanging demos as generated for TAX3D ({kind})",
        source_license=SOURCE_LICENSE,
        units=UNITS,
        command=options.command,
        description=description,
        hub_license=options.hub_license or "other",
        tags=["dedo", "cloth", kind],
        details=details,
    )


def convert_dedo_goals(raw_dir: Path, repo_id: str, root: Path, options: ConversionOptions) -> ConversionSummary:
    """Goal demos (`demo_*.npz`) -> goal-prediction dataset (goal = start + flow)."""
    counts = options.point_counts(DEFAULT_POINT_COUNTS["cloth_hang"])
    demos = list_goal_demos(Path(raw_dir), options.split)
    task = options.task or DEFAULT_TASK
    card = _card(
        options,
        "goal demos",
        "TAX-DPD goal-prediction dataset of cloth hanging: `action` is the cloth's goal cloud (start + flow), "
        "row i corresponding to row i of `observation.pointcloud.object`; the scene is the hangers. "
        "Frames of an episode are independent farthest-point samplings of one demo.",
        card_details(options, *counts),
    )
    return write_dataset(
        demos,
        lambda demo: goal_episode(demo, options, counts, task),
        source_name="dedo",
        repo_id=repo_id,
        root=Path(root),
        features=goal_prediction_features(*counts, with_transform=False),
        fps=GOAL_DATASET_FPS,
        card=card,
        options=options,
    )


def convert_dedo_rollouts(
    raw_dir: Path, repo_id: str, root: Path, options: ConversionOptions, *, fps: int = 10, successful: bool = False
) -> ConversionSummary:
    """Policy rollouts (zarr) -> `gc_dp3` time-series dataset."""
    counts = options.point_counts(DEFAULT_POINT_COUNTS["cloth_hang"])
    demos, stores = list_rollouts(Path(raw_dir), options.split)
    first = next(iter(stores.values()))
    dims = (first.state_dim, first.action_dim)
    task = options.task or DEFAULT_TASK
    card = _card(
        options,
        "policy rollouts",
        "Goal-conditioned cloth-policy (`gc_dp3`) dataset: one rollout per episode, with the cloth, the hangers, "
        "the cloth's ground-truth goal cloud, both end effectors' state and the 6-d end-effector action.",
        {
            "split": options.split,
            "sampling": (
                f"cloth: {counts[0]} farthest points chosen once per episode on its first step (only the true "
                f"vertex count of `data/cloth`, never the zero padding), same rows for the goal; hangers: "
                f"{counts[1]} farthest points per step (seed {options.seed})"
            ),
            "next.success": "last step of every episode (--successful-demos)" if successful else "unknown, False",
            "fps": f"{fps} (the source stores no rate)",
        },
    )
    return write_dataset(
        demos,
        lambda demo: rollout_episode(demo, stores, options, counts, dims, task, successful),
        source_name="dedo",
        repo_id=repo_id,
        root=Path(root),
        features=cloth_policy_features(*counts, state_dim=dims[0], action_dim=dims[1]),
        fps=fps,
        card=card,
        options=options,
    )
