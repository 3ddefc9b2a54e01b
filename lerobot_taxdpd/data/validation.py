"""Input checks that fail early with a message naming the offending argument, file or field.

Every public entry point (policy API, dataset writer, converters, geometry) validates here, so a bad
cloud never reaches the network or a half-written dataset. `name` is whatever the caller wants the user
to read: an argument name, or "demo_3.npz: field 'action_pc'".
"""

from __future__ import annotations

import numpy as np
import torch


class PointCloudError(ValueError):
    """A point cloud or transform that cannot be used, with the argument or field it came from."""


#: Largest coordinate magnitude a cloud may hold. No scene spans a thousand kilometres (nor, in millimetres, a
#: kilometre), and beyond it the float32 arithmetic of the model and of the datasets overflows into NaN.
MAX_COORDINATE = 1e6


def _shape(x) -> tuple[int, ...]:
    return tuple(x.shape)


def check_point_cloud(
    points,
    name: str,
    *,
    min_points: int = 1,
    num_points: int | None = None,
    batched: bool = False,
) -> None:
    """Raise `PointCloudError` unless `points` is a finite (N, 3) cloud, or (..., N, 3) when `batched`."""
    if not isinstance(points, (np.ndarray, torch.Tensor)):
        raise PointCloudError(f"{name}: expected a numpy array or torch tensor, got {type(points).__name__}")
    if isinstance(points, torch.Tensor) and (points.layout != torch.strided or points.is_meta):
        raise PointCloudError(f"{name}: expected a dense tensor of values, got {points.layout} on {points.device}")
    shape = _shape(points)
    expected = "(..., N, 3)" if batched else "(N, 3)"
    if (batched and len(shape) < 2) or (not batched and len(shape) != 2) or shape[-1] != 3:
        raise PointCloudError(f"{name}: expected shape {expected}, got {shape}")
    n = shape[-2]
    if n < min_points:
        what = "is empty" if n == 0 else f"has {n} points"
        raise PointCloudError(f"{name}: {what}; at least {min_points} points are needed")
    if num_points is not None and n != num_points:
        raise PointCloudError(f"{name}: expected {num_points} points, got {n}")
    if points.dtype in (torch.bool, np.bool_) or not (
        np.issubdtype(points.dtype, np.floating) if isinstance(points, np.ndarray) else points.is_floating_point()
    ):
        raise PointCloudError(f"{name}: expected floating-point coordinates, got dtype {points.dtype}")
    finite = np.isfinite(points) if isinstance(points, np.ndarray) else torch.isfinite(points)
    if not bool(finite.all()):
        bad = int((~finite).sum())
        raise PointCloudError(f"{name}: contains {bad} NaN or infinite coordinate values")
    peak = _peak(points)
    if peak > MAX_COORDINATE:
        raise PointCloudError(
            f"{name}: a coordinate reaches {peak:.3g}, beyond the +-{MAX_COORDINATE:g} any real scene stays "
            "within (check the units); float32 arithmetic would overflow"
        )


def _peak(points) -> float:
    """The largest coordinate magnitude, 0 for an empty batch."""
    if isinstance(points, np.ndarray):
        return float(np.abs(points).max()) if points.size else 0.0
    return float(points.abs().max()) if points.numel() else 0.0


def check_same_shape(a, b, name_a: str, name_b: str) -> None:
    """Corresponding clouds (row i of one pairs with row i of the other) must have identical shapes."""
    if _shape(a) != _shape(b):
        raise PointCloudError(
            f"{name_a} and {name_b}: shapes {_shape(a)} and {_shape(b)} differ, but their rows must correspond"
        )


def check_rigid_transform(transform, name: str, *, atol: float = 1e-4) -> None:
    """Raise unless `transform` is a finite 4x4 proper rigid transform (orthonormal rotation, det +1)."""
    if not isinstance(transform, (np.ndarray, torch.Tensor)):
        raise PointCloudError(f"{name}: expected a 4x4 array, got {type(transform).__name__}")
    if _shape(transform) != (4, 4):
        raise PointCloudError(f"{name}: expected shape (4, 4), got {_shape(transform)}")
    t = np.asarray(transform.detach().cpu() if isinstance(transform, torch.Tensor) else transform, dtype=np.float64)
    if not np.isfinite(t).all():
        raise PointCloudError(f"{name}: contains NaN or infinite values")
    r = t[:3, :3]
    ortho = np.abs(r.T @ r - np.eye(3)).max()
    det = np.linalg.det(r)
    if ortho > atol or abs(det - 1.0) > atol:
        raise PointCloudError(
            f"{name}: not a rigid transform (|R^T R - I| = {ortho:.2e}, det R = {det:.6f}; need orthonormal, det +1)"
        )
    if np.abs(t[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > atol:
        raise PointCloudError(f"{name}: last row must be [0, 0, 0, 1], got {t[3].tolist()}")
