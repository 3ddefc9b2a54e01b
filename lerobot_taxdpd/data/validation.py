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
    check_values: bool = True,
) -> None:
    """Raise `PointCloudError` unless `points` is a finite (N, 3) cloud, or (..., N, 3) when `batched`.

    `check_values=False` checks type, shape and dtype only; the caller then checks `value_faults` itself."""
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
    if check_values:
        raise_value_faults(name, *value_faults(points).tolist())


def value_faults(points) -> np.ndarray | torch.Tensor:
    """[number of NaN or infinite coordinates, largest finite coordinate magnitude] of a cloud, computed where
    the cloud lives: one read-back checks it, and a training step can defer that read-back (a GPU keeps going)."""
    if isinstance(points, np.ndarray):
        finite = np.isfinite(points)
        peak = np.abs(np.where(finite, points, 0.0)).max() if points.size else 0.0
        return np.array([(~finite).sum(), peak], dtype=np.float64)
    finite = torch.isfinite(points)
    magnitude = torch.where(finite, points.abs(), 0.0)
    peak = magnitude.amax() if points.numel() else magnitude.new_zeros(())
    return torch.stack([(~finite).sum().to(peak.dtype), peak]).double()


def check_values_together(clouds: dict[str, np.ndarray | torch.Tensor]) -> None:
    """`check_point_cloud`'s value checks of several named clouds, read back from their device in one transfer."""
    faults = {name: value_faults(cloud) for name, cloud in clouds.items()}
    tensors = [f for f in faults.values() if isinstance(f, torch.Tensor)]
    read = iter(torch.stack([f.to(tensors[0].device) for f in tensors]).tolist() if tensors else [])
    for name, found in faults.items():
        raise_value_faults(name, *(found.tolist() if isinstance(found, np.ndarray) else next(read)))


def raise_value_faults(name: str, nonfinite: float, peak: float) -> None:
    """Raise `PointCloudError` for the faults `value_faults` found in the cloud called `name`."""
    if nonfinite:
        raise PointCloudError(f"{name}: contains {int(nonfinite)} NaN or infinite coordinate values")
    if peak > MAX_COORDINATE:
        raise PointCloudError(
            f"{name}: a coordinate reaches {peak:.3g}, beyond the +-{MAX_COORDINATE:g} any real scene stays "
            "within (check the units); float32 arithmetic would overflow"
        )


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
