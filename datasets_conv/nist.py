"""NIST Assembly Task Board connector-insertion demos -> goal-prediction dataset, one task per connector.

Layouts read, per connector folder (its name is the connector type, e.g. `waterproof`, `dsub25`, `ssd`):

    <connector>/{train,test}/<demo>.npz   the authors' per-demo files: action_init_points (N, 3) plug,
    <connector>/<demo>.npz                anchor_points (M, 3) socket, goal_tf (4, 4)
    <connector>/<demo>/action.ply         raw teach data: plug and socket clouds (open3d-readable .ply,
    <connector>/<demo>/anchor.ply         usually millimetres) and goal_tf.npy (4, 4) in the same units
    <connector>/<demo>/goal_tf.npy

goal_tf convention (both layouts): it maps the goal points onto the initial points, initial = goal_tf @ goal
in homogeneous column vectors (the authors write it `goal_pcd @ goal_tf = initial_action_pcd`), so
T* = inverse(goal_tf) and the goal cloud is T* applied to the initial plug cloud. An optional
`action_goal_points` field is a separate capture without point correspondence and is not used.
With `train/` and `test/` folders those are the split (the paper's 16 training / 4 held-out demos); without,
the held-out demos are drawn per connector from `--seed` (`--holdout-fraction`, 4 of 20 by default).
`--split val` and `--split test` both select the held-out part.
"""

from __future__ import annotations

import zlib
from collections import Counter
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
from datasets_conv.raw_io import DemoError, as_cloud, as_finite, layout_error, natural_key, open_npz, read_field
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo
from lerobot_taxdpd.data.schema import DEFAULT_POINT_COUNTS, GOAL_DATASET_FPS, goal_prediction_features
from lerobot_taxdpd.data.validation import check_rigid_transform

NPZ_FIELDS = ("action_init_points", "anchor_points", "goal_tf")
TEACH_FILES = ("action.ply", "anchor.ply", "goal_tf.npy")
UNIT_SCALES = {"m": 1.0, "mm": 1e-3}
UNIT_NAMES = {"m": "metres", "mm": "millimetres"}

#: Bounding-box diagonal (in source units) above which `--units auto` reads a demo as millimetres. A plug
#: with its socket spans well under a metre, i.e. tens to hundreds of millimetres.
MILLIMETRE_EXTENT = 5.0


def _demos_in(folder: Path) -> list[Path]:
    """Per-demo .npz files and teach-data folders directly inside `folder`."""
    entries = [*folder.glob("*.npz"), *(p for p in folder.iterdir() if (p / TEACH_FILES[0]).is_file())]
    return sorted(entries, key=natural_key)


def _is_connector(folder: Path) -> bool:
    return folder.is_dir() and (any((folder / s).is_dir() for s in ("train", "test")) or bool(_demos_in(folder)))


def find_connectors(raw_dir: Path) -> list[Path]:
    """`raw_dir` itself if it is one connector's folder, else its connector sub-folders."""
    if not raw_dir.is_dir():
        raise FileNotFoundError(f"--raw-dir {raw_dir}: no such folder")
    if _is_connector(raw_dir):
        return [raw_dir]
    connectors = sorted((p for p in raw_dir.iterdir() if _is_connector(p)), key=natural_key)
    if not connectors:
        teach = ", ".join(TEACH_FILES)
        problem = f"no connector folders with .npz demos or teach data ({teach})"
        raise layout_error(raw_dir, problem, lambda p: any(_is_connector(c) for c in p.iterdir()))
    return connectors


def split_demos(connector: Path, split: str, seed: int, holdout_fraction: float) -> list[Path]:
    """The connector's demos of one split; the held-out draw depends only on the seed and connector name."""
    if any((connector / s).is_dir() for s in ("train", "test")):
        parts = {"train": ["train"], "val": ["test"], "test": ["test"], "all": ["train", "test"]}[split]
        return [d for part in parts if (connector / part).is_dir() for d in _demos_in(connector / part)]
    demos = _demos_in(connector)
    if split == "all":
        return demos
    held = round(len(demos) * holdout_fraction)
    order = np.random.default_rng([seed, zlib.crc32(connector.name.encode())]).permutation(len(demos))
    chosen = set(order[:held].tolist()) if split in ("val", "test") else set(order[held:].tolist())
    return [d for i, d in enumerate(demos) if i in chosen]


def _read_ply(path: Path, source: str) -> np.ndarray:
    import open3d as o3d

    cloud = np.asarray(o3d.io.read_point_cloud(str(path), format="ply").points)
    if cloud.shape[0] == 0:
        raise DemoError(f"{source}: field '{path.name}' is empty or not a readable .ply point cloud")
    return cloud


def read_demo(path: Path, source: str) -> tuple[tuple[str, ...], tuple[np.ndarray, ...]]:
    """Field names and raw (plug, socket, goal_tf) of a demo in source units, from either layout."""
    if not path.is_dir():
        archive = open_npz(path)
        return NPZ_FIELDS, tuple(read_field(archive, source, f) for f in NPZ_FIELDS)
    for name in TEACH_FILES:
        if not (path / name).is_file():
            raise DemoError(f"{source}: missing file '{name}' (teach data needs {', '.join(TEACH_FILES)})")
    try:
        goal_tf = np.load(path / TEACH_FILES[2], allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise DemoError(f"{source}: field '{TEACH_FILES[2]}' cannot be read ({exc})") from exc
    return TEACH_FILES, (_read_ply(path / TEACH_FILES[0], source), _read_ply(path / TEACH_FILES[1], source), goal_tf)


def detect_units(plug: np.ndarray, socket: np.ndarray) -> str:
    """'mm' when the demo spans more than `MILLIMETRE_EXTENT` source units, else 'm'."""
    both = np.concatenate([plug, socket])
    return "mm" if float(np.linalg.norm(both.max(0) - both.min(0))) > MILLIMETRE_EXTENT else "m"


def demo_episode(demo: DemoRef, options: ConversionOptions, counts: tuple[int, int], units: str):
    """Samplings of one demo in metres, its task and its source unit; the goal is T* = inverse(goal_tf)
    applied to the sampled plug."""
    num_object, num_scene = counts
    (plug_field, socket_field, tf_field), (plug_raw, socket_raw, goal_tf) = read_demo(demo.path, demo.source)
    plug = as_cloud(plug_raw, demo.source, plug_field, min_points=num_object)
    socket = as_cloud(socket_raw, demo.source, socket_field, min_points=num_scene)
    goal_tf = as_finite(goal_tf, demo.source, tf_field, (4, 4))
    check_rigid_transform(goal_tf, f"{demo.source}: field '{tf_field}'")
    unit = detect_units(plug, socket) if units == "auto" else units
    scale = UNIT_SCALES[unit]
    transform = np.linalg.inv(goal_tf)
    transform[:3, 3] *= scale
    plug, socket = plug * scale, socket * scale
    frames = sampled_frames(demo.source, plug, socket, counts, options, transform=transform)
    return frames, f"insert the {demo.key} connector into its socket", unit


def convert_nist(
    raw_dir: Path,
    repo_id: str,
    root: Path,
    options: ConversionOptions,
    *,
    units: str = "auto",
    holdout_fraction: float = 0.2,
) -> ConversionSummary:
    """Convert one or several connectors' demos; the connector type is each episode's task."""
    if units not in ("auto", *UNIT_SCALES):
        raise ValueError(f"units: expected auto, m or mm, got {units!r}")
    if not 0.0 <= holdout_fraction < 1.0:
        raise ValueError(f"holdout_fraction: expected a value in [0, 1), got {holdout_fraction}")
    counts = options.point_counts(DEFAULT_POINT_COUNTS["nist"])
    connectors = find_connectors(Path(raw_dir))
    demos = [
        DemoRef(str(path), path, connector.name)
        for connector in connectors
        for path in split_demos(connector, options.split, options.seed, holdout_fraction)
    ]
    detected: Counter = Counter()
    details = {
        "connectors": ", ".join(c.name for c in connectors),
        "held-out rule": (
            "the source's train/ and test/ folders"
            if any((c / "test").is_dir() for c in connectors)
            else f"{holdout_fraction:g} of each connector's demos, drawn with seed {options.seed}"
        ),
        "goal_tf convention": "initial = goal_tf @ goal (column vectors); goal.transform = inverse(goal_tf)",
        **card_details(options, *counts),
    }
    card = DatasetCardInfo(
        source="NIST Assembly Task Board 1 connector-insertion demos (per-demo .npz or raw teach .ply/.npy)",
        source_license="no licence stated by the source; ask the data's authors before redistributing",
        units="metres (millimetre sources scaled by 0.001)",
        command=options.command,
        description=(
            "TAX-DPD goal-prediction dataset of connector insertion: the plug cloud, the socket cloud, the plug's "
            "goal cloud (row i corresponds to row i of the plug) and T*. The task string names the connector."
        ),
        hub_license=options.hub_license or "other",
        tags=["nist", "insertion"],
        details=details,
    )

    def episode(demo: DemoRef):
        frames, task, unit = demo_episode(demo, options, counts, units)
        detected[unit] += 1  # the writer reads the card when it publishes, so the tally is complete by then
        card.details["source units"] = ", ".join(f"{UNIT_NAMES[u]}: {n} demos" for u, n in sorted(detected.items()))
        card.details["source units"] += " (given by --units)" if units != "auto" else " (detected from cloud extent)"
        return frames, options.task or task

    summary = write_dataset(
        demos,
        episode,
        source_name="nist",
        repo_id=repo_id,
        root=Path(root),
        features=goal_prediction_features(*counts, with_transform=True),
        fps=GOAL_DATASET_FPS,
        card=card,
        options=options,
    )
    summary.notes.append(f"source units: {card.details.get('source units', 'none')}")
    return summary
