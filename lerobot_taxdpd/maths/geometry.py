"""Point-cloud and rigid-body geometry shared by the model, the converters and the benchmarks.

Every function takes torch tensors with optional leading batch dimensions; the public helpers that users
call directly (`estimate_rigid_transform`, `fit_rigid_transform`, `farthest_point_indices`) also accept
numpy arrays and answer in the type they were given.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from contextvars import ContextVar

import numpy as np
import torch
from torch import Tensor

from lerobot_taxdpd.data.point_order import ORDER_TOLERANCE
from lerobot_taxdpd.data.validation import check_point_cloud, check_same_shape

ArrayLike = Tensor | np.ndarray

_DEVICE_CODE_PATHS: ContextVar[bool] = ContextVar("device_code_paths", default=False)


@contextlib.contextmanager
def device_code_paths() -> Iterator[None]:
    """Within it, CPU tensors take the code path that other devices take (no CPU-only library shortcuts),
    so that counting the ops on the CPU counts what a GPU would launch."""
    token = _DEVICE_CODE_PATHS.set(True)
    try:
        yield
    finally:
        _DEVICE_CODE_PATHS.reset(token)


def takes_cpu_shortcuts(x: Tensor) -> bool:
    """Whether code on `x` may take a CPU-only shortcut: on the CPU, outside `device_code_paths`."""
    return x.device.type == "cpu" and not _DEVICE_CODE_PATHS.get()


def _as_tensor(x: ArrayLike) -> tuple[Tensor, bool]:
    """Return `x` as a float tensor and whether it came in as numpy (to convert the answer back)."""
    if isinstance(x, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64)), True
    return x, False


def _like_input(x: Tensor, was_numpy: bool, dtype=np.float64):
    return x.detach().cpu().numpy().astype(dtype) if was_numpy else x


# --------------------------------------------------------------------------------------------- sampling
def farthest_point_sample(points: Tensor, num_samples: int, start_index: Tensor | None = None) -> Tensor:
    """Batched farthest point sampling: (..., N, 3) -> indices (..., num_samples), in selection order.

    Deterministic: starts from `start_index` (default point 0). On the CPU each cloud goes through
    fpsample's exact FPS (2-7x faster at the model's sizes; the device loop's points, in its order up to swaps
    at float near-ties); elsewhere a loop sequential over samples and vectorised over the batch (see
    `_farthest_point_loop`).
    """
    batch_shape = points.shape[:-2]
    n = points.shape[-2]
    if num_samples > n:
        raise ValueError(f"cannot sample {num_samples} points from a cloud of {n}")
    flat = points.detach().reshape(-1, n, points.shape[-1])
    b = flat.shape[0]
    starts = start_index.reshape(b) if start_index is not None else torch.zeros(b, dtype=torch.long)
    if takes_cpu_shortcuts(flat):
        import fpsample

        clouds, firsts = flat.float().numpy(), starts.tolist()
        chosen = [
            fpsample.fps_sampling(cloud, num_samples, start_idx=int(first))
            for cloud, first in zip(clouds, firsts, strict=True)
        ]
        return torch.from_numpy(np.stack(chosen).astype(np.int64)).reshape(*batch_shape, num_samples)
    return _farthest_point_loop(flat, num_samples, starts.to(points.device)).reshape(*batch_shape, num_samples)


#: The largest pairwise-distance table (bytes) that farthest point sampling off the CPU builds to save launches.
FPS_DISTANCE_TABLE_BYTES = 2**30


def _farthest_point_loop(flat: Tensor, num_samples: int, current: Tensor) -> Tensor:
    """(B, N, 3) -> (B, num_samples) from start indices `current` (B,), sequential over samples. With the
    (B, N, N) distances built once (when they fit in `FPS_DISTANCE_TABLE_BYTES`), a sample is three ops (a
    row of the table, the running minimum, its argmax) instead of five; the indices are stacked at the end."""
    b, n, _ = flat.shape
    table = None
    if b * n * n * flat.element_size() <= FPS_DISTANCE_TABLE_BYTES:
        table = torch.cdist(flat, flat, compute_mode="donot_use_mm_for_euclid_dist")  # exact, as the loop
    nearest = torch.full(flat.shape[:2], float("inf"), dtype=flat.dtype, device=flat.device)
    chosen = []
    for i in range(num_samples):
        chosen.append(current)
        if i == num_samples - 1:
            break
        if table is not None:
            distances = table.gather(1, current.view(-1, 1, 1).expand(-1, 1, n)).squeeze(1)
        else:
            centre = flat.gather(1, current.view(-1, 1, 1).expand(-1, 1, flat.shape[-1]))
            distances = torch.linalg.vector_norm(flat - centre, dim=-1)
        nearest = torch.minimum(nearest, distances)
        current = nearest.argmax(-1)
    return torch.stack(chosen, 1)


def farthest_point_sample_parts(
    parts: list[Tensor], counts: list[int], starts: list[Tensor] | None = None
) -> list[Tensor]:
    """FPS of several batched clouds at once: parts[i] (B_i, N_i, 3) -> (B_i, counts[i]), each from `starts[i]`
    (B_i,) (default: point 0).

    Off the CPU, all parts go through one loop (each padded with copies of its start point, which are never
    farther than any other point), so the number of ops follows the largest count, not the sum of them."""
    if starts is None:
        starts = [torch.zeros(part.shape[0], dtype=torch.long, device=part.device) for part in parts]
    if takes_cpu_shortcuts(parts[0]):
        return [farthest_point_sample(p, count, start) for p, count, start in zip(parts, counts, starts, strict=True)]
    for part, count in zip(parts, counts, strict=True):
        if count > part.shape[1]:
            raise ValueError(f"cannot sample {count} points from a cloud of {part.shape[1]}")
    n = max(part.shape[1] for part in parts)
    padded = []
    for part, start in zip(parts, starts, strict=True):
        first = gather_points(part.detach(), start.view(-1, 1).to(part.device))
        padded.append(torch.cat([part.detach(), first.expand(-1, n - part.shape[1], -1)], 1))
    firsts = torch.cat([start.to(parts[0].device) for start in starts])
    indices = _farthest_point_loop(torch.cat(padded), max(counts), firsts).split([p.shape[0] for p in parts])
    return [chosen[:, :count] for chosen, count in zip(indices, counts, strict=True)]


def is_farthest_point_prefix(points: Tensor, count: int, tolerance: float = ORDER_TOLERANCE) -> Tensor:
    """(B, N, 3) -> (B,) bool: is each cloud's prefix of `count` points its FPS from point 0 (up to ties within
    the relative `tolerance`), i.e. is every point i < count a farthest point of the cloud from points 0..i-1?

    A cloud recorded in FPS order passes, and its prefix then serves as its reduction and its layout. Checking
    an order is a handful of parallel ops (distances to the prefix, their running minimum down the prefix),
    where finding one is a loop of `count` steps: on a GPU, 3 * `count` launches. Clouds whose (B, count, N)
    distances would exceed `FPS_DISTANCE_TABLE_BYTES` are answered False (unchecked: treated as unordered)."""
    if count <= 1 or points.shape[0] * count * points.shape[1] * points.element_size() > FPS_DISTANCE_TABLE_BYTES:
        return torch.full((points.shape[0],), count <= 1, dtype=torch.bool, device=points.device)
    distances = torch.cdist(points[:, : count - 1], points, compute_mode="donot_use_mm_for_euclid_dist")
    nearest = distances.cummin(1).values  # [b, i, j]: from point j to the nearest of points 0..i
    chosen = nearest.diagonal(offset=1, dim1=1, dim2=2)  # [b, i]: point i + 1's, which FPS must pick next
    return (chosen >= nearest.amax(-1) * (1 - tolerance)).all(-1)


def farthest_point_indices(points: ArrayLike, num_samples: int, start_index: int = 0) -> np.ndarray:
    """Indices of `num_samples` farthest points of one (N, 3) cloud, for data conversion.

    Uses fpsample's bucketed KD-tree FPS, which is exact and far faster than a Python loop on the
    30-60k-point clouds of raw demos. Returns sorted-by-selection-order int64 indices, so the same
    indices can be applied to a corresponding cloud (start and goal rows stay paired). fpsample (1.0.2)
    does not start at `start_index` itself but at a point chosen deterministically from it: different
    values still give different exact samplings, reproducibly. Asked for every point, it still orders them: the
    datasets record their clouds in FPS order (`lerobot_taxdpd.data.point_order`), whatever the render's size.
    """
    import fpsample

    array = points.detach().cpu().numpy() if isinstance(points, Tensor) else np.asarray(points)
    check_point_cloud(array, "points", min_points=1)
    n = array.shape[0]
    if num_samples > n:
        raise ValueError(f"points: cannot sample {num_samples} points from a cloud of {n}")
    height = 3 if n < 5_000 else 7 if n < 100_000 else 9
    idx = fpsample.bucket_fps_kdline_sampling(array.astype(np.float32), num_samples, h=height, start_idx=start_index)
    return np.asarray(idx, dtype=np.int64)


def gather_points(points: Tensor, indices: Tensor) -> Tensor:
    """points (B, N, C), indices (B, ...) -> (B, ..., C)."""
    b = points.shape[0]
    flat = indices.reshape(b, -1)
    out = torch.gather(points, 1, flat.unsqueeze(-1).expand(-1, -1, points.shape[-1]))
    return out.reshape(*indices.shape, points.shape[-1])


def nearest_indices(points: Tensor, anchors: Tensor, k: int = 1) -> Tensor:
    """Indices (B, N, k) of the k anchors (B, n, 3) nearest to each point (B, N, 3), nearest first."""
    return torch.cdist(points, anchors).topk(k, dim=-1, largest=False).indices


def nearest_points(points: Tensor, centres: Tensor, count: int) -> Tensor:
    """The `count` points of each cloud (B, N, 3) nearest its centre (B, 3), nearest first: (B, count, 3)."""
    return gather_points(points, nearest_indices(centres.unsqueeze(1), points, count).squeeze(1))


def lift_point_motion(points: Tensor, anchors: Tensor, anchor_goals: Tensor, num_neighbors: int = 8) -> Tensor:
    """Carry the predicted motion of anchor points to every point of the cloud they were sampled from.

    points (B, N, 3), anchors (B, n, 3), anchor_goals (B, K, n, 3) -> goals (B, K, N, 3). Each point's goal
    is the least-squares affine map of its nearest anchors onto their goals, evaluated at the point: a
    fixed linear combination of those goals whose weights sum to one and reproduce any affine motion, so
    rigid placements are lifted exactly and deformations are followed locally. The fit is the minimum-norm
    least-squares solution, so flat (coplanar) neighbourhoods, as depth cameras see faces, stay exact too.
    """
    b, k_samples, n, _ = anchor_goals.shape
    k = min(num_neighbors, n)
    neighbours = nearest_indices(points, anchors, k)  # (B, N, k)
    offsets = (gather_points(anchors, neighbours) - points.unsqueeze(2)).double()  # (B, N, k, 3)
    offsets = offsets / offsets.square().sum(-1).mean(-1).sqrt().clamp_min(1e-12)[..., None, None]  # unit size
    design = torch.cat([offsets, torch.ones_like(offsets[..., :1])], -1)  # (B, N, k, 4)
    weights = torch.linalg.pinv(design, rtol=1e-6)[..., 3, :].to(anchor_goals.dtype)  # (B, N, k): the intercept
    per_sample = neighbours.unsqueeze(1).expand(b, k_samples, *neighbours.shape[1:]).reshape(b * k_samples, -1, k)
    gathered = gather_points(anchor_goals.reshape(b * k_samples, n, 3), per_sample)  # (B*K, N, k, 3)
    lifted = (weights.repeat_interleave(k_samples, 0).unsqueeze(-1) * gathered).sum(2)
    return lifted.reshape(b, k_samples, points.shape[1], 3)


# ------------------------------------------------------------------------------------------- rotations
def skew(v: Tensor) -> Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v.unbind(-1)
    return torch.stack(
        [torch.stack([zero, -z, y], -1), torch.stack([z, zero, -x], -1), torch.stack([-y, x, zero], -1)], -2
    )


def axis_angle_to_matrix(axis: Tensor, angle: Tensor) -> Tensor:
    """Rodrigues' formula: unit axes (..., 3) and angles (...) -> rotations (..., 3, 3)."""
    k = skew(axis)
    eye = torch.eye(3, dtype=axis.dtype, device=axis.device).expand_as(k)
    s = torch.sin(angle)[..., None, None]
    c = torch.cos(angle)[..., None, None]
    return eye + s * k + (1.0 - c) * (k @ k)


def random_axis_angle_rotation(
    batch_size: int, angle_std: float, *, generator: torch.Generator | None = None, device=None, dtype=None
) -> Tensor:
    """Rotations about axes uniform on S^2 by angles ~ N(0, angle_std^2) (the paper's rotation noise)."""
    axis = torch.randn(batch_size, 3, generator=generator, device=device, dtype=dtype)
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    angle = torch.randn(batch_size, generator=generator, device=device, dtype=dtype) * angle_std
    return axis_angle_to_matrix(axis, angle)


def rotation_about_z(angle: Tensor) -> Tensor:
    """Angles (...) -> rotations about +z (..., 3, 3)."""
    c, s = torch.cos(angle), torch.sin(angle)
    zero, one = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack(
        [torch.stack([c, -s, zero], -1), torch.stack([s, c, zero], -1), torch.stack([zero, zero, one], -1)], -2
    )


def rotation_angle(rotation: Tensor) -> Tensor:
    """Geodesic angle (radians) of rotation matrices (..., 3, 3)."""
    trace = rotation.diagonal(dim1=-2, dim2=-1).sum(-1)
    return torch.acos(((trace - 1.0) / 2.0).clamp(-1.0, 1.0))


def small_rotation_between(reference: Tensor, moved: Tensor) -> Tensor:
    """The rotation vector w (radians) whose small turn best maps `reference` onto `moved` (..., N, 3), both
    centred, in the least-squares sense: sum_i r_i x m_i = J w with J the inertia tensor of `reference`.

    The linearised Kabsch fit: exact to first order in the angle, and unlike an SVD it has a finite gradient
    for round shapes, whose covariance has repeated singular values. Only the rigid part of `moved`'s offset
    moves it; stretching and point-wise scatter do not, but a cloud squashed across one axis shows less of a turn
    about the others (as to any rigid fit). The 3 x 3 solve does not wait for the device.
    """
    torque = torch.linalg.cross(reference, moved, dim=-1).sum(-2)
    squared = reference.pow(2).sum(-1)
    eye = torch.eye(3, dtype=reference.dtype, device=reference.device)
    inertia = squared.sum(-1)[..., None, None] * eye - reference.transpose(-1, -2) @ reference
    ridge = 1e-6 * inertia.diagonal(dim1=-2, dim2=-1).sum(-1).clamp_min(1e-12)[..., None, None] * eye
    return torch.linalg.solve_ex(inertia + ridge, torque.unsqueeze(-1), check_errors=False)[0].squeeze(-1)


def principal_spreads(points: Tensor) -> Tensor:
    """The standard deviation of centred points (..., N, 3) along each of their principal axes, ascending
    (..., 3): a cloud's extent without its orientation (a box's thickness, width and length).

    eigvalsh's gradient stays finite where two axes spread alike (a round plug); the spreads are floored at a
    thousandth of the cloud's overall spread, so that a cloud squashed flat still has a finite gradient.
    """
    covariance = points.transpose(-1, -2) @ points / points.shape[-2]
    variances = torch.linalg.eigvalsh(covariance).clamp_min(0.0)
    floor = 1e-6 * variances.sum(-1, keepdim=True).clamp_min(1e-12)
    return (variances + floor).sqrt()


def matrix_to_rotation_6d(rotation: Tensor) -> Tensor:
    """First two columns of R, flattened (Zhou et al. 2019): (..., 3, 3) -> (..., 6)."""
    return torch.cat([rotation[..., :, 0], rotation[..., :, 1]], dim=-1)


def rotation_6d_to_matrix(d6: Tensor) -> Tensor:
    """Gram-Schmidt of two 3-vectors into a rotation matrix: (..., 6) -> (..., 3, 3).

    Degenerate inputs (a vanishing first vector, or a second one parallel to it) fall back to the nearest
    axes of the identity, so the answer is always a rotation (an untrained clean-sample predictor says 0).
    """
    a1, a2 = d6[..., :3], d6[..., 3:]
    eye = torch.eye(3, dtype=d6.dtype, device=d6.device)
    b1 = _unit_or(a1, eye[0])
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    fallback = torch.where((b1[..., :1].abs() < 0.9), eye[0], eye[1])  # an axis not parallel to b1
    fallback = fallback - (b1 * fallback).sum(-1, keepdim=True) * b1
    b2 = _unit_or(torch.where(a2.norm(dim=-1, keepdim=True) > 1e-6, a2, fallback), eye[1])
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def _unit_or(v: Tensor, default: Tensor) -> Tensor:
    norm = v.norm(dim=-1, keepdim=True)
    return torch.where(norm > 1e-6, v / norm.clamp_min(1e-12), default.expand_as(v))


def quaternion_xyzw_to_matrix(quaternion: ArrayLike):
    """Unit quaternions in (x, y, z, w) order (..., 4) -> rotations (..., 3, 3)."""
    q, was_numpy = _as_tensor(quaternion)
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    x, y, z, w = q.unbind(-1)
    rotation = torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            torch.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            torch.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    return _like_input(rotation, was_numpy)


def matrix_to_quaternion_xyzw(rotation: ArrayLike):
    """Rotations (..., 3, 3) -> unit quaternions (x, y, z, w) with w >= 0 (inverse of the function above).

    Shepperd's method: build the quaternion from whichever of w, x, y, z has the largest magnitude, which
    stays accurate near 180-degree rotations where the trace formula alone loses precision.
    """
    r_in, was_numpy = _as_tensor(rotation)
    r = r_in.double()

    def e(i: int, j: int) -> Tensor:
        return r[..., i, j]

    m00, m11, m22 = e(0, 0), e(1, 1), e(2, 2)
    candidates = torch.stack(
        [
            torch.stack([e(2, 1) - e(1, 2), e(0, 2) - e(2, 0), e(1, 0) - e(0, 1), 1 + m00 + m11 + m22], -1),
            torch.stack([1 + m00 - m11 - m22, e(0, 1) + e(1, 0), e(0, 2) + e(2, 0), e(2, 1) - e(1, 2)], -1),
            torch.stack([e(0, 1) + e(1, 0), 1 - m00 + m11 - m22, e(1, 2) + e(2, 1), e(0, 2) - e(2, 0)], -1),
            torch.stack([e(0, 2) + e(2, 0), e(1, 2) + e(2, 1), 1 - m00 - m11 + m22, e(1, 0) - e(0, 1)], -1),
        ],
        -2,
    )  # (..., 4, 4): row k is 4*q_k times q, for k = w, x, y, z
    pivots = torch.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    best = pivots.argmax(-1, keepdim=True)
    q = torch.gather(candidates, -2, best.unsqueeze(-1).expand(*best.shape, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    q = torch.where(q[..., 3:4] < 0, -q, q)
    return _like_input(q if was_numpy else q.to(r_in.dtype), was_numpy)


def pose_to_matrix(position: ArrayLike, quaternion_xyzw: ArrayLike):
    """Position (..., 3) and xyzw quaternion (..., 4) -> homogeneous transforms (..., 4, 4)."""
    p, was_numpy = _as_tensor(position)
    r, _ = _as_tensor(quaternion_xyzw_to_matrix(quaternion_xyzw))
    transform = make_transform(r.to(p.dtype), p)
    return _like_input(transform, was_numpy)


def make_transform(rotation: Tensor, translation: Tensor) -> Tensor:
    """(..., 3, 3) and (..., 3) -> (..., 4, 4)."""
    transform = torch.zeros(*rotation.shape[:-2], 4, 4, dtype=rotation.dtype, device=rotation.device)
    transform[..., :3, :3] = rotation
    transform[..., :3, 3] = translation
    transform[..., 3, 3] = 1.0
    return transform


def transform_points(transform: ArrayLike, points: ArrayLike):
    """Apply (..., 4, 4) transforms to (..., N, 3) points."""
    if isinstance(transform, np.ndarray) and isinstance(points, np.ndarray):
        # Plain numpy: torch's thread pool costs far more than this matmul on a busy CPU (converters).
        t = np.asarray(transform, dtype=np.float64)
        return np.asarray(points, dtype=np.float64) @ np.swapaxes(t[..., :3, :3], -1, -2) + t[..., None, :3, 3]
    t, was_numpy = _as_tensor(transform)
    p, _ = _as_tensor(points)
    out = p @ t[..., :3, :3].transpose(-1, -2) + t[..., None, :3, 3]
    return _like_input(out, was_numpy)


# ------------------------------------------------------------------------------------- rigid fitting
def _kabsch(src: Tensor, dst: Tensor, weights: Tensor | None = None) -> Tensor:
    """Weighted least-squares rigid transform with dst ~ R src + t; (..., N, 3) -> (..., 4, 4).

    Runs in float64: the SVD of a 3x3 covariance is cheap and float32 loses the sub-millimetre precision
    insertion tasks need.
    """
    src64, dst64 = src.double(), dst.double()
    if weights is None:
        weights = torch.ones(src.shape[:-1], dtype=torch.float64, device=src.device)
    w = weights.double().unsqueeze(-1)
    w_sum = w.sum(-2, keepdim=True).clamp_min(1e-12)
    src_c = (w * src64).sum(-2, keepdim=True) / w_sum
    dst_c = (w * dst64).sum(-2, keepdim=True) / w_sum
    cov = ((src64 - src_c) * w).transpose(-1, -2) @ (dst64 - dst_c)
    u, _, vh = torch.linalg.svd(cov)
    d = torch.sign(torch.linalg.det(vh.transpose(-1, -2) @ u.transpose(-1, -2)))
    d = torch.where(d == 0, torch.ones_like(d), d)
    fix = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    rotation = vh.transpose(-1, -2) @ fix @ u.transpose(-1, -2)
    translation = dst_c.squeeze(-2) - (rotation @ src_c.transpose(-1, -2)).squeeze(-1)
    return make_transform(rotation, translation).to(src.dtype)


def fit_rigid_transform(src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None):
    """Procrustes/Kabsch fit of T with dst ~ T src over corresponding rows; (..., N, 3) -> (..., 4, 4)."""
    s, was_numpy = _as_tensor(src)
    d, _ = _as_tensor(dst)
    check_same_shape(s, d, "src", "dst")
    check_point_cloud(s, "src", min_points=3, batched=s.dim() > 2)
    check_point_cloud(d, "dst", min_points=3, batched=d.dim() > 2)
    w = _as_tensor(weights)[0] if weights is not None else None
    return _like_input(_kabsch(s, d, w), was_numpy)


def estimate_rigid_transform(
    src: ArrayLike,
    dst: ArrayLike,
    *,
    threshold: float | None = None,
    num_hypotheses: int = 256,
    refinements: int = 2,
    generator: torch.Generator | None = None,
):
    """RANSAC-SVD: the rigid transform T with dst ~ T src that the most correspondences agree with.

    Each hypothesis is a Kabsch fit to 3 random correspondences; the one with most inliers
    (`|T src_i - dst_i| < threshold`) is refit by SVD on its inliers, `refinements` times. Leading batch
    dimensions are processed together. `threshold` defaults to 5% of the RMS radius of `src`, so it
    scales with the object. Returns (T (..., 4, 4), inlier_mask (..., N) bool).
    """
    s, was_numpy = _as_tensor(src)
    d, _ = _as_tensor(dst)
    check_same_shape(s, d, "src", "dst")
    check_point_cloud(s, "src", min_points=3, batched=s.dim() > 2)
    check_point_cloud(d, "dst", min_points=3, batched=d.dim() > 2)
    batch_shape, n = s.shape[:-2], s.shape[-2]
    s64 = s.reshape(-1, n, 3).double()
    d64 = d.reshape(-1, n, 3).double()
    b = s64.shape[0]
    if threshold is None:
        centred = s64 - s64.mean(-2, keepdim=True)
        threshold_t = 0.05 * centred.square().sum(-1).mean(-1).sqrt().clamp_min(1e-9)  # (b,)
    else:
        if not threshold > 0:
            raise ValueError(f"threshold: must be positive, got {threshold}")
        threshold_t = torch.full((b,), float(threshold), dtype=torch.float64, device=s.device)

    # Three distinct indices per hypothesis: sample without replacement via random keys.
    keys_device = generator.device if generator is not None else s.device
    keys = torch.rand(b, num_hypotheses, n, generator=generator, device=keys_device).to(s.device)
    triples = keys.topk(3, dim=-1).indices  # (b, H, 3)
    picks = triples.unsqueeze(-1).expand(-1, -1, -1, 3)
    src_triples = torch.gather(s64.unsqueeze(1).expand(-1, num_hypotheses, -1, -1), 2, picks)
    dst_triples = torch.gather(d64.unsqueeze(1).expand(-1, num_hypotheses, -1, -1), 2, picks)
    hypotheses = _kabsch(src_triples, dst_triples)  # (b, H, 4, 4)
    moved = s64.unsqueeze(1) @ hypotheses[..., :3, :3].transpose(-1, -2) + hypotheses[..., None, :3, 3]
    residual = (moved - d64.unsqueeze(1)).norm(dim=-1)  # (b, H, N)
    inliers = residual < threshold_t[:, None, None]
    best = inliers.sum(-1).argmax(-1)  # (b,)
    mask = inliers[torch.arange(b, device=s.device), best]
    mask = torch.where(mask.sum(-1, keepdim=True) >= 3, mask, torch.ones_like(mask))
    transform = _kabsch(s64, d64, mask.double())
    for _ in range(refinements):
        residual = (s64 @ transform[..., :3, :3].transpose(-1, -2) + transform[..., None, :3, 3] - d64).norm(dim=-1)
        refined = residual < threshold_t[:, None]
        mask = torch.where(refined.sum(-1, keepdim=True) >= 3, refined, mask)
        transform = _kabsch(s64, d64, mask.double())
    transform = transform.reshape(*batch_shape, 4, 4).to(s.dtype)
    mask = mask.reshape(*batch_shape, n)
    if was_numpy:
        return transform.numpy(), mask.numpy()
    return transform, mask
