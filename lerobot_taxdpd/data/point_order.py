"""Whether a dataset's clouds are in farthest-point order from their point 0, recorded beside its metadata.

A cloud in that order is its own farthest point sampling: FPS from its point 0 picks its points in the stored
order, so any prefix is the FPS of the whole cloud. The procedural tasks, the cloth task and the converters
reduce every cloud by FPS before writing it, so the dataset writer checks each cloud it writes and records the
answer per field (`POINT_ORDER_FILE`). A training step on such a dataset takes its encoders' set-abstraction
layouts as prefixes instead of running FPS: on a GPU that loop is hundreds of launches a step at the paper's
size. A dataset without the file is treated as unordered, which is always correct, only slower.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

POINT_ORDER_FILE = "meta/taxdpd_point_order.json"

#: Relative tolerance on the distance comparisons: float32 clouds written and read back compare equal.
ORDER_TOLERANCE = 1e-6


def is_farthest_point_ordered(cloud: np.ndarray) -> bool:
    """Is every point i of `cloud` (N, 3) a farthest point from points 0..i-1 among points i..N-1?

    fpsample's exact FPS answers the common case (2 ms for 1024 points); where its order differs from the
    stored one, the distances decide, so equally far points (ties, duplicates) may come in either order."""
    import fpsample

    points = np.asarray(cloud, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"expected a cloud of shape (N, 3), got {points.shape}")
    order = fpsample.fps_sampling(points.astype(np.float32), len(points), start_idx=0)
    if np.array_equal(order, np.arange(len(points))):
        return True
    nearest = np.full(len(points), np.inf)  # distance of each point to the nearest of points 0..i-1
    for i in range(1, len(points)):
        np.minimum(nearest, np.linalg.norm(points - points[i - 1], axis=1), out=nearest)
        rest = nearest[i:]
        if nearest[i] < rest.max() * (1 - ORDER_TOLERANCE):
            return False
    return True


def write_point_order(dataset_root: str | Path, ordered: Mapping[str, bool]) -> Path:
    """Record, per cloud field, whether every cloud of the dataset is in farthest-point order."""
    path = Path(dataset_root) / POINT_ORDER_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"farthest_point_ordered": dict(ordered)}, indent=2))
    return path


def read_point_order(dataset_root: str | Path) -> dict[str, bool]:
    """Per cloud field, whether the dataset says its clouds are in farthest-point order ({} when it says nothing)."""
    path = Path(dataset_root) / POINT_ORDER_FILE
    if not path.is_file():
        return {}
    try:
        recorded = json.loads(path.read_text())["farthest_point_ordered"]
    except (json.JSONDecodeError, KeyError, TypeError) as error:
        raise ValueError(f"{path}: expected {{'farthest_point_ordered': {{field: bool}}}} ({error})") from error
    if not isinstance(recorded, dict) or not all(isinstance(v, bool) for v in recorded.values()):
        raise ValueError(f"{path}: field 'farthest_point_ordered' must map cloud fields to true or false")
    return recorded
