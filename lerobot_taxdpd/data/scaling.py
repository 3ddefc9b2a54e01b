"""Dataset scaling: one isotropic factor that brings the median object radius to `object_scale` model units.

The factor is computed once from the training data and stored in the checkpoint's config, so inference
rescales exactly as training did. Object, scene and goal always share it (never per-axis statistics).
The median object radius is a statistic of the dataset: the dataset writer, which sees every cloud, records
it in `meta/taxdpd_scale.json`; datasets made elsewhere lack that file, and their parquet files are scanned.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import torch
from torch import Tensor

from lerobot_taxdpd.data.schema import OBJECT_KEY

#: The dataset's scale statistics, beside LeRobot's own metadata (which ignores files it does not know).
SCALE_FILE = "meta/taxdpd_scale.json"

logger = logging.getLogger(__name__)


def object_radius(points: Tensor) -> Tensor:
    """Largest distance of an object's points from its centroid: (B, N, 3) -> (B,)."""
    return (points - points.mean(dim=-2, keepdim=True)).norm(dim=-1).amax(dim=-1)


def read_object_clouds(dataset_root: str | Path, max_frames: int = 2000) -> np.ndarray:
    """Up to `max_frames` evenly spaced object clouds (F, N, 3) straight from a LeRobot dataset's parquet files."""
    files = sorted(Path(dataset_root).glob("data/*/*.parquet"))
    if not files:
        raise FileNotFoundError(f"{dataset_root}: no data/*/*.parquet files (is this a LeRobot v3 dataset?)")
    column = pq.read_table(files, columns=[OBJECT_KEY]).column(OBJECT_KEY)
    rows = np.unique(np.linspace(0, len(column) - 1, min(max_frames, len(column))).round().astype(np.int64))
    array = column.take(rows).combine_chunks()
    if isinstance(array, pa.ExtensionArray):  # datasets' Array2D wraps a list<list<float>> storage
        array = array.storage
    values = pc.list_flatten(pc.list_flatten(array)).to_numpy()
    return values.reshape(len(rows), -1, 3)


def write_scale_stats(dataset_root: str | Path, object_radii: Sequence[float]) -> Path:
    """Record the median of the object radii of every frame (metres) in the dataset's metadata."""
    radius = float(torch.tensor(list(object_radii), dtype=torch.float64).median())
    path = Path(dataset_root) / SCALE_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps({"field": OBJECT_KEY, "median_object_radius": radius, "frames": len(object_radii)}, indent=2)
    )
    return path


def median_object_radius(dataset_root: str | Path) -> float:
    """The dataset's median object radius (metres): from its metadata, or scanned from its parquet files."""
    path = Path(dataset_root) / SCALE_FILE
    if path.is_file():
        return float(json.loads(path.read_text())["median_object_radius"])
    logger.info(
        "%s: no %s (a dataset not written by lerobot_taxdpd); scanning its object clouds", dataset_root, SCALE_FILE
    )
    clouds = torch.tensor(read_object_clouds(dataset_root), dtype=torch.float64)
    return float(object_radius(clouds).median())


def estimate_point_scale(dataset_root: str | Path, object_scale: float) -> float:
    """Model units per metre for a dataset: object_scale / median object radius."""
    radius = median_object_radius(dataset_root)
    if not radius > 0:
        raise ValueError(f"{dataset_root}: field '{OBJECT_KEY}' has zero extent; cannot derive point_scale")
    scale = object_scale / radius
    logger.info("point_scale = %.4g model units per metre (median object radius %.4g m)", scale, radius)
    return scale
