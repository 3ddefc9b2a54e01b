"""A few raw demos of every layout the converters read, so a user can try each converter without the real data.

`taxdpd-convert samples --out DIR` writes them and prints the command that converts each folder; the
converter tests build their inputs with the same writers. No public sample of these formats can be
downloaded, so the writers follow the documented keys exactly, quirks included: RPDiff dicts in 0-d object
arrays with both pose layouts and the chunked variant, DEDO goal demos with pickled dict fields, DP3-layout
zarr rollouts with zero-padded cloth and a true-count field, NIST .npz demos and millimetre .ply + 4x4 .npy
teach data with the `initial = goal_tf @ goal` convention. Rotations are built here from first principles,
not with the converters' geometry, so the tests do not trust the code they check. The clouds are synthetic
(random blobs and a cloth grid), not real objects: they show the layouts, not a task worth training on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


# ------------------------------------------------------------------------------------------- geometry
def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """xyzw unit quaternion -> 3x3 rotation."""
    x, y, z, w = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of xyzw quaternions: R(a * b) = R(a) @ R(b)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def random_quat(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit quaternion (xyzw)."""
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def rigid(rotation: np.ndarray, translation) -> np.ndarray:
    """4x4 homogeneous transform from a rotation and a translation."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """`transform` applied to (N, 3) points."""
    return points @ transform[:3, :3].T + transform[:3, 3]


# ---------------------------------------------------------------------------------------------- RPDiff
def rpdiff_demo(rng: np.random.Generator, *, nested_pose: bool = False, n_child: int = 700, n_parent: int = 1400):
    """One RPDiff demo dict (values as RPDiff saves them) and its true T*."""
    child = rng.normal(scale=0.04, size=(n_child, 3)) + [0.45, -0.1, 1.25]
    parent = rng.normal(scale=0.08, size=(n_parent, 3)) + [0.6, 0.15, 1.3]
    q_start, p_start = random_quat(rng), rng.uniform(-0.2, 0.2, 3) + [0.4, 0.0, 1.2]
    q_rel, t_rel = random_quat(rng), rng.uniform(-0.3, 0.3, 3)
    true_transform = rigid(quat_to_matrix(q_rel), t_rel)
    q_final = quat_multiply(q_rel, q_start)
    p_final = quat_to_matrix(q_rel) @ p_start + t_rel
    start_pose = [*p_start.tolist(), *q_start.tolist()]
    final_pose = [*p_final.tolist(), *q_final.tolist()]
    if nested_pose:
        start_pose, final_pose = [start_pose], [final_pose]
    parent_pose = [0.6, 0.15, 1.2, 0.0, 0.0, 0.0, 1.0]
    demo = {
        "multi_obj_names": {"parent": "syn_rack_0", "child": "mug_0"},
        "multi_obj_start_pcd": {"parent": parent, "child": child},
        "multi_obj_final_pcd": {"parent": parent, "child": apply(true_transform, child)},
        "multi_obj_start_obj_pose": {"parent": parent_pose, "child": start_pose},
        "multi_obj_final_obj_pose": {"parent": parent_pose, "child": final_pose},
        "multi_obj_mesh_file": {"parent": "racks/syn_rack_0.obj", "child": "mugs/mug_0.obj"},
        "success": True,
    }
    return demo, true_transform


def _npz_values(demo: dict) -> dict:
    """How RPDiff's np.savez stores a demo: every dict becomes a 0-d object array."""
    return {k: np.array(v, dtype=object) if isinstance(v, dict) else np.asarray(v) for k, v in demo.items()}


def save_rpdiff_demo(path: Path, demo: dict) -> Path:
    """One demo per file, as RPDiff's `demo_aug_<i>.npz`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **_npz_values(demo))
    return path


def save_rpdiff_chunk(path: Path, demos: list[dict]) -> Path:
    """Chunked variant: keys "0".."k" each hold a whole demo dict (itself a 0-d object array)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **{str(i): np.array(_npz_values(d), dtype=object) for i, d in enumerate(demos)})
    return path


def write_split_info(demo_dir: Path, splits: dict[str, list[str]]) -> None:
    """RPDiff's `split_info/*.txt`: the file names of each split, one a line."""
    files = {"train": "train_split.txt", "val": "train_val_split.txt", "test": "test_split.txt"}
    (demo_dir / "split_info").mkdir(parents=True, exist_ok=True)
    for split, names in splits.items():
        (demo_dir / "split_info" / files[split]).write_text("\n".join(names) + "\n")


# ------------------------------------------------------------------------------------------------ DEDO
def cloth_grid(rng: np.random.Generator, n: int = 25, hole: tuple[int, int, int, int] = (8, 12, 10, 13)):
    """Cloth vertices of an n x n grid less a rectangular hole (rows x0:x1, cols y0:y1)."""
    x0, x1, y0, y1 = hole
    keep = [(i, j) for i in range(n) for j in range(n) if not (x0 <= i < x1 and y0 <= j < y1)]
    grid = np.array(keep, dtype=np.float64) / (n - 1) * 2.0 - 1.0
    noise = rng.normal(scale=1e-3, size=(len(grid), 3))
    return np.column_stack([grid, np.zeros(len(grid))]) + [0.0, 3.0, 8.0] + noise


def dedo_goal_demo(rng: np.random.Generator, n_anchor: int = 1024) -> dict:
    """One TAX3D goal demo: the cloth at the start, its flow to the goal, hangers, pickled dict fields."""
    cloth = cloth_grid(rng)
    flow = np.column_stack([np.zeros(len(cloth)), -3.0 + 0.1 * cloth[:, 0], -1.0 + 0.2 * cloth[:, 1]])
    return {
        "action_pc": cloth.astype(np.float32),
        "action_seg": np.zeros(len(cloth), dtype=np.int64),
        "anchor_pc": (rng.normal(scale=0.5, size=(n_anchor, 3)) + [0.0, 0.0, 6.0]).astype(np.float32),
        "anchor_seg": np.ones(n_anchor, dtype=np.int64),
        "flow": flow.astype(np.float32),
        "deform_data": np.array(
            {
                "deform_transform": {"rotation": [0.0, 0.0, 0.3], "translation": [0.0, 3.0, 8.0]},
                "deform_params": {
                    "num_holes": 1,
                    "node_density": 25,
                    "w": 1.0,
                    "h": 1.0,
                    "holes": [{"x0": 8, "x1": 11, "y0": 10, "y1": 12}],
                },
            },
            dtype=object,
        ),
        "rigid_data": np.array(
            {0: {"rigid_transform": {"rotation": [0, 0, 0.5], "translation": [0, 0, 0]}}}, dtype=object
        ),
    }


def save_dedo_goal_demo(path: Path, demo: dict) -> Path:
    """One goal demo per file, as TAX3D's `demo_<i>.npz`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **demo)
    return path


def write_dedo_rollouts(path: Path, rng: np.random.Generator, lengths: list[int], padded: int = 625, **override):
    """A DP3-layout zarr store (Blosc zstd) of cloth rollouts; returns the raw arrays written."""
    import numcodecs
    import zarr

    steps = sum(lengths)
    cloth = cloth_grid(rng)
    vertices = len(cloth)
    action_pcd = np.zeros((steps, padded, 3), np.float32)
    ground_truth = np.zeros((steps, padded, 3), np.float32)
    for t in range(steps):
        action_pcd[t, :vertices] = cloth + [0.0, -0.2 * t, -0.05 * t]
        ground_truth[t, :vertices] = cloth + [0.0, -3.0, -1.0]
    anchor = np.repeat((rng.normal(scale=0.5, size=(1, 1024, 3)) + [0, 0, 6]).astype(np.float32), steps, axis=0)
    data = {
        "action_pcd": action_pcd,
        "anchor_pcd": anchor,
        "state": rng.normal(size=(steps, 12)).astype(np.float32),
        "action": rng.normal(size=(steps, 6)).astype(np.float32),
        "cloth": np.full((steps, 1), vertices, dtype=np.int64),
        "point_cloud": np.concatenate([action_pcd[:, :512], anchor[:, :512]], axis=1),
        "ground_truth": ground_truth,
    }
    data.update(override)
    compressor = numcodecs.Blosc(cname="zstd", clevel=3, shuffle=numcodecs.Blosc.NOSHUFFLE)
    root = zarr.group(str(path))
    group = root.create_group("data")
    for name, array in data.items():
        group.create_dataset(name, data=array, chunks=(2, *array.shape[1:]), compressor=compressor)
    ends = np.cumsum(lengths).astype(np.int64)
    root.create_group("meta").create_dataset("episode_ends", data=ends, compressor=None)
    return data


# ------------------------------------------------------------------------------------------------ NIST
def nist_demo(rng: np.random.Generator, *, scale: float = 1.0, n_plug: int = 700, n_socket: int = 1400):
    """(initial plug, socket, goal_tf, true goal plug) with initial = goal_tf @ goal; lengths in metres * scale."""
    goal = rng.normal(scale=0.01, size=(n_plug, 3)) + [0.3, 0.0, 0.05]
    socket = rng.normal(scale=0.02, size=(n_socket, 3)) + [0.3, 0.0, 0.03]
    angle = np.deg2rad(rng.uniform(-10, 10))
    about_y = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    goal_to_initial = rigid(about_y, [rng.uniform(-0.005, 0.005), 0.02, 0.1 + rng.uniform(0, 0.005)])
    initial = apply(goal_to_initial, goal)
    goal_tf = goal_to_initial.copy()
    goal_tf[:3, 3] *= scale
    return initial * scale, socket * scale, goal_tf, goal * scale


def save_nist_npz(path: Path, initial, socket, goal_tf) -> Path:
    """The authors' per-demo .npz, with the unused separate goal capture they also store."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        path,
        action_init_points=initial.astype(np.float32),
        anchor_points=socket.astype(np.float32),
        action_goal_points=np.zeros((5, 3), np.float32),  # a separate capture, no correspondence
        goal_tf=goal_tf.astype(np.float32),
    )
    return path


def save_nist_teach(folder: Path, initial, socket, goal_tf) -> Path:
    """Raw teach data: .ply clouds written by open3d and a 4x4 goal_tf .npy, all in the same units."""
    import open3d as o3d

    folder.mkdir(parents=True, exist_ok=True)
    for name, points in (("action.ply", initial), ("anchor.ply", socket)):
        cloud = o3d.geometry.PointCloud()
        cloud.points = o3d.utility.Vector3dVector(points)
        o3d.io.write_point_cloud(str(folder / name), cloud)
    np.save(folder / "goal_tf.npy", goal_tf)
    return folder


# --------------------------------------------------------------------------------------- sample folders
RPDIFF_DIR = "rpdiff/mug_rack_easy_single/task_name_mug_on_rack"
RPDIFF_CHUNKED_DIR = "rpdiff/mug_rack_easy_single_chunked/task_name_mug_on_rack"

#: One conversion per layout `write_samples` writes: (dataset name, converter, raw folder under --out, options).
CONVERSIONS = (
    ("rpdiff", "rpdiff", RPDIFF_DIR, ("--split", "train")),
    ("rpdiff_chunked", "rpdiff", RPDIFF_CHUNKED_DIR, ()),
    ("cloth_goals", "dedo", "dedo", ("--kind", "goal", "--split", "train")),
    ("cloth_rollouts", "dedo", "dedo", ("--kind", "policy", "--split", "train")),
    ("nist", "nist", "nist", ("--split", "train")),
    ("nist_teach", "nist", "nist_teach", ("--units", "mm")),
)


def _write_rpdiff(task_dir: Path, rng: np.random.Generator, demos: int) -> None:
    """One file per demo, both pose layouts, and split files holding all but the last demo for training."""
    names = [f"demo_aug_{i}.npz" for i in range(demos)]
    for i, name in enumerate(names):
        save_rpdiff_demo(task_dir / name, rpdiff_demo(rng, nested_pose=i % 2 == 1)[0])
    write_split_info(task_dir, {"train": names[:-1], "val": names[-1:], "test": names[-1:]})


def _write_rpdiff_chunked(task_dir: Path, rng: np.random.Generator, demos: int) -> None:
    """RPDiff's chunked variant: numbered folders of files that each hold two whole demos."""
    for i in range(0, demos, 2):
        chunk = [rpdiff_demo(rng)[0] for _ in range(min(2, demos - i))]
        save_rpdiff_chunk(task_dir / str(i // 2) / "demo_aug_0.npz", chunk)


def _write_dedo(dataset: Path, rng: np.random.Generator, demos: int) -> None:
    """Goal demos and rollout stores of a TAX3D cloth dataset, all but one for training, one held out."""
    for split, count in (("train", demos - 1), ("val_ood", 1)):
        for i in range(count):
            save_dedo_goal_demo(dataset / f"{split}_tax3d" / f"demo_{i}.npz", dedo_goal_demo(rng))
        write_dedo_rollouts(dataset / f"{split}.zarr", rng, [4 + i % 3 for i in range(count)])


def _write_nist(raw_dir: Path, rng: np.random.Generator, demos: int) -> None:
    """The authors' .npz demos in metres, split into train/ and test/ folders of one connector."""
    for i in range(demos):
        split = "test" if i == demos - 1 else "train"
        save_nist_npz(raw_dir / "waterproof" / split / f"demo_{i}.npz", *nist_demo(rng)[:3])


def _write_nist_teach(raw_dir: Path, rng: np.random.Generator, demos: int) -> None:
    """Raw teach data in millimetres (.ply clouds and a goal_tf .npy per demo), no split folders."""
    for i in range(demos):
        save_nist_teach(raw_dir / "dsub" / f"demo_{i}", *nist_demo(rng, scale=1000.0)[:3])


_WRITERS = {
    RPDIFF_DIR: _write_rpdiff,
    RPDIFF_CHUNKED_DIR: _write_rpdiff_chunked,
    "dedo": _write_dedo,
    "nist": _write_nist,
    "nist_teach": _write_nist_teach,
}


def write_samples(out: Path, demos: int = 4, seed: int = 0) -> None:
    """Write `demos` demos of every layout under `out` (seeded, so the same files every time)."""
    if demos < 2:
        raise ValueError(f"demos: at least 2 (one to train on, one held out), got {demos}")
    rng = np.random.default_rng(seed)
    for folder, writer in _WRITERS.items():
        writer(out / folder, rng, demos)


def conversion_commands(out: Path) -> list[list[str]]:
    """The `taxdpd-convert` arguments that convert each layout under `out` into `data/sample_<name>`."""
    return [
        [
            source,
            "--raw-dir",
            str(out / raw),
            *options,
            "--repo-id",
            f"me/sample_{name}",
            "--root",
            f"data/sample_{name}",
        ]
        for name, source, raw, options in CONVERSIONS
    ]
