"""Training augmentations: they move clouds rigidly, within their stated ranges, and keep what the goal means."""

from __future__ import annotations

import math

import pytest
import torch

from lerobot_taxdpd import TaxDPDConfig
from lerobot_taxdpd.policies.taxdpd.augmentation import random_start_pose, random_z_rotation


def _batch(batch: int = 256, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    obj = torch.rand(batch, 16, 3, generator=g, dtype=torch.float64) * 0.1
    scene = torch.rand(batch, 48, 3, generator=g, dtype=torch.float64) + 0.5
    goal = obj + torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64)
    return obj, scene, goal


def _yaw_of_rigid_turn(before: torch.Tensor, after: torch.Tensor) -> torch.Tensor:
    """Yaw (rad) of the vertical-axis rotation taking each row's centred cloud `before` to `after`."""
    a = before - before.mean(1, keepdim=True)
    b = after - after.mean(1, keepdim=True)
    cross = (a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]).sum(1)
    dot = (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]).sum(1)
    return torch.atan2(cross, dot)


@pytest.mark.parametrize("max_angle", [180.0, 30.0, 0.0])
def test_scene_turn_is_one_rigid_yaw_within_its_range_for_all_three_clouds(max_angle):
    obj, scene, goal = _batch()
    turned = random_z_rotation(obj, scene, goal, max_angle, generator=torch.Generator().manual_seed(1))
    yaws = [_yaw_of_rigid_turn(before, after) for before, after in zip((obj, scene, goal), turned, strict=True)]
    torch.testing.assert_close(yaws[0], yaws[1])  # one angle for object, scene and goal: the task is unchanged
    torch.testing.assert_close(yaws[2], yaws[1])
    limit = math.radians(max_angle)
    assert yaws[1].abs().max() <= limit + 1e-9
    if max_angle > 0:  # the draws cover the range, not a corner of it
        assert yaws[1].abs().max() > 0.9 * limit and yaws[1].min() < -0.5 * limit and yaws[1].max() > 0.5 * limit
    heights = [x[..., 2] for x in (obj, scene, goal)]
    for height, cloud in zip(heights, turned, strict=True):
        torch.testing.assert_close(cloud[..., 2], height)  # about the vertical: heights unchanged
    torch.testing.assert_close(turned[1].mean(1), scene.mean(1))  # pivot: the scene centroid


def test_start_pose_turns_only_the_object_about_its_centroid_within_its_yaw_range():
    obj, _, _ = _batch()
    moved = random_start_pose(obj, max_yaw_deg=30.0, max_tilt_deg=0.0, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(moved.mean(1), obj.mean(1))
    torch.testing.assert_close(torch.cdist(moved, moved), torch.cdist(obj, obj))
    assert _yaw_of_rigid_turn(obj, moved).abs().max() <= math.radians(30.0) + 1e-9


@pytest.mark.parametrize("value", [-1.0, 181.0])
def test_a_scene_turn_range_outside_the_circle_is_rejected_by_name(value):
    with pytest.raises(ValueError, match="z_rotation_range"):
        TaxDPDConfig(z_rotation_range=value)
