"""Rigid fitting, RANSAC-SVD, farthest point sampling and rotation helpers."""

import math

import numpy as np
import pytest
import torch

from lerobot_taxdpd.data.validation import PointCloudError
from lerobot_taxdpd.maths.geometry import (
    estimate_rigid_transform,
    farthest_point_indices,
    farthest_point_sample,
    fit_rigid_transform,
    lift_point_motion,
    make_transform,
    matrix_to_rotation_6d,
    quaternion_xyzw_to_matrix,
    random_axis_angle_rotation,
    rotation_6d_to_matrix,
    rotation_angle,
    transform_points,
)


def random_transform(generator: torch.Generator) -> torch.Tensor:
    rotation = random_axis_angle_rotation(1, 2.0, generator=generator, dtype=torch.float64)[0]
    translation = torch.randn(3, generator=generator, dtype=torch.float64)
    return make_transform(rotation, translation)


@pytest.mark.parametrize("seed", range(5))
def test_ransac_is_exact_on_clean_correspondences(seed):
    g = torch.Generator().manual_seed(seed)
    src = torch.randn(300, 3, generator=g, dtype=torch.float64) * 0.05
    truth = random_transform(g)
    estimate, inliers = estimate_rigid_transform(src, transform_points(truth, src), generator=g)
    assert torch.allclose(estimate, truth, atol=1e-9)
    assert bool(inliers.all())


@pytest.mark.parametrize("seed", range(5))
def test_ransac_recovers_transform_with_40_percent_gross_outliers(seed):
    g = torch.Generator().manual_seed(seed)
    src = torch.randn(500, 3, generator=g, dtype=torch.float64) * 0.05
    truth = random_transform(g)
    dst = transform_points(truth, src) + torch.randn(500, 3, generator=g, dtype=torch.float64) * 1e-4
    outliers = torch.rand(500, generator=g) < 0.4
    dst[outliers] += torch.randn(int(outliers.sum()), 3, generator=g, dtype=torch.float64) * 0.2
    estimate, inliers = estimate_rigid_transform(src, dst, generator=g)
    assert (estimate[:3, 3] - truth[:3, 3]).norm() < 1e-3
    relative = estimate[:3, :3].T @ truth[:3, :3]
    assert math.degrees(float(rotation_angle(relative))) < 0.2
    assert (inliers == ~outliers).float().mean() > 0.98
    # A plain least-squares fit is ruined by the same outliers: RANSAC is doing the work.
    naive = fit_rigid_transform(src, dst)
    assert (naive[:3, 3] - truth[:3, 3]).norm() > 10 * (estimate[:3, 3] - truth[:3, 3]).norm()


def test_ransac_batches_and_round_trips_numpy():
    g = torch.Generator().manual_seed(0)
    src = torch.randn(2, 3, 100, 3, generator=g, dtype=torch.float64)
    truths = torch.stack([torch.stack([random_transform(g) for _ in range(3)]) for _ in range(2)])
    dst = transform_points(truths, src)
    batched, mask = estimate_rigid_transform(src, dst)
    assert batched.shape == (2, 3, 4, 4) and mask.shape == (2, 3, 100)
    assert torch.allclose(batched, truths, atol=1e-9)
    as_numpy, mask_np = estimate_rigid_transform(src[0, 0].numpy(), dst[0, 0].numpy())
    assert isinstance(as_numpy, np.ndarray) and isinstance(mask_np, np.ndarray)
    np.testing.assert_allclose(as_numpy, truths[0, 0].numpy(), atol=1e-9)


@pytest.mark.parametrize(
    ("src", "dst", "message"),
    [
        (np.zeros((2, 3)), np.zeros((2, 3)), "src: has 2 points; at least 3"),
        (np.full((10, 3), np.nan), np.zeros((10, 3)), "src: contains 30 NaN"),
        (np.zeros((10, 3)), np.zeros((9, 3)), "src and dst: shapes"),
        (np.zeros((10, 2)), np.zeros((10, 2)), "expected shape"),
    ],
)
def test_ransac_rejects_bad_input_with_the_argument_named(src, dst, message):
    with pytest.raises(PointCloudError, match=message):
        estimate_rigid_transform(src, dst)


def test_kabsch_never_returns_a_reflection():
    g = torch.Generator().manual_seed(1)
    src = torch.randn(50, 3, generator=g, dtype=torch.float64)
    mirrored = src * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)
    transform = fit_rigid_transform(src, mirrored)
    assert torch.linalg.det(transform[:3, :3]) == pytest.approx(1.0)


def test_farthest_point_sampling_spreads_and_batches():
    corners = torch.tensor([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    cloud = torch.cat([torch.full((100, 3), 0.5) + torch.rand(100, 3) * 0.01, corners])[None]
    picked = farthest_point_sample(cloud, 9)[0]
    assert len(set(picked.tolist())) == 9
    assert set(range(100, 108)) <= set(picked.tolist())  # all 8 corners come before any inner point but the start
    batch = torch.rand(3, 200, 3, generator=torch.Generator().manual_seed(0))
    together = farthest_point_sample(batch, 20)
    for i in range(3):
        assert torch.equal(together[i], farthest_point_sample(batch[i : i + 1], 20)[0])


def test_farthest_point_indices_cover_better_than_random():
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(20_000, 3))
    fps = cloud[farthest_point_indices(cloud, 256)]
    rand = cloud[rng.choice(len(cloud), 256, replace=False)]

    def coverage_radius(subset):
        d = ((cloud[::20, None] - subset[None]) ** 2).sum(-1)
        return np.sqrt(d.min(1)).max()

    assert coverage_radius(fps) < 0.7 * coverage_radius(rand)
    with pytest.raises(ValueError, match="cannot sample 300"):
        farthest_point_indices(cloud[:100], 300)


def test_quaternion_xyzw_and_6d_rotations():
    quarter_turn_z = np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])
    np.testing.assert_allclose(
        quaternion_xyzw_to_matrix(quarter_turn_z), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12
    )
    rotations = random_axis_angle_rotation(8, 2.0, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    assert torch.allclose(rotation_6d_to_matrix(matrix_to_rotation_6d(rotations)), rotations, atol=1e-12)


def _moved(clouds: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """Each cloud (B, N, 3) under each of its transforms (B, T, 4, 4): (B, T, N, 3)."""
    pairs = zip(clouds, transforms, strict=True)
    return torch.stack([torch.stack([transform_points(t, cloud) for t in ts]) for cloud, ts in pairs])


def test_lifting_anchor_motion_is_exact_for_rigid_placements_even_on_flat_clouds():
    g = torch.Generator().manual_seed(3)
    solid = torch.rand(2, 400, 3, generator=g, dtype=torch.float64) * 0.05
    flat = solid.clone()
    flat[..., 2] = 0.0  # one face seen by a depth camera: every neighbourhood is coplanar
    for points in (solid, flat):
        anchors = points[:, farthest_point_sample(points[0], 64)]
        transforms = torch.stack([random_transform(g) for _ in range(6)]).reshape(2, 3, 4, 4)
        anchor_goals, expected = _moved(anchors, transforms), _moved(points, transforms)
        lifted = lift_point_motion(points, anchors, anchor_goals)
        assert lifted.shape == (2, 3, 400, 3)
        torch.testing.assert_close(lifted, expected, atol=1e-6, rtol=0)
