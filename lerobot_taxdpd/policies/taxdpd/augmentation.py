"""Training-time augmentation of (object, scene, goal) batches; correspondence between object and goal rows
is always kept (the same indices are applied to both)."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lerobot_taxdpd.maths.geometry import axis_angle_to_matrix, farthest_point_sample_parts, rotation_about_z


def _uniform(batch: int, like: Tensor, generator: torch.Generator | None) -> Tensor:
    device = generator.device if generator is not None else like.device
    return torch.rand(batch, generator=generator, device=device, dtype=like.dtype).to(like.device)


def random_z_rotation(
    object_points: Tensor,
    scene_points: Tensor,
    goal_points: Tensor,
    max_angle_deg: float = 180.0,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Rotate all three clouds by one angle ~ U(+-max_angle) about the vertical axis through the scene centroid
    (180 deg: the whole circle, as the paper does)."""
    angle = (2 * _uniform(object_points.shape[0], object_points, generator) - 1) * math.radians(max_angle_deg)
    rotation = rotation_about_z(angle).transpose(-1, -2)
    pivot = scene_points.mean(dim=1, keepdim=True)
    return tuple((x - pivot) @ rotation + pivot for x in (object_points, scene_points, goal_points))


def random_start_pose(
    object_points: Tensor, max_yaw_deg: float, max_tilt_deg: float, generator: torch.Generator | None = None
) -> Tensor:
    """Turn each object cloud alone about its centroid: a yaw ~ U(+-max_yaw) after a tilt ~ U(0, max_tilt)
    about a random horizontal axis. The goal is left as it is, so row i still goes where it went."""
    b = object_points.shape[0]
    yaw = (2 * _uniform(b, object_points, generator) - 1) * math.radians(max_yaw_deg)
    tilt = _uniform(b, object_points, generator) * math.radians(max_tilt_deg)
    heading = _uniform(b, object_points, generator) * (2 * math.pi)
    axis = torch.stack([torch.cos(heading), torch.sin(heading), torch.zeros_like(heading)], -1)
    rotation = (rotation_about_z(yaw) @ axis_angle_to_matrix(axis, tilt)).transpose(-1, -2)
    centroid = object_points.mean(dim=1, keepdim=True)
    return (object_points - centroid) @ rotation + centroid


def _rank(values: Tensor) -> Tensor:
    """Rank of each entry within its row (0 = smallest)."""
    return values.argsort(dim=1).argsort(dim=1)


def refill_indices(keep: Tensor, num_points: int, generator: torch.Generator | None = None) -> Tensor:
    """`num_points` indices of kept points per row (random order, kept points repeated when too few)."""
    device = generator.device if generator is not None else keep.device
    keys = torch.rand(keep.shape, generator=generator, device=device).to(keep.device)
    order = torch.where(keep, keys, keys + 2.0).argsort(dim=1)
    counts = keep.sum(dim=1, keepdim=True).clamp_min(1)
    position = torch.arange(num_points, device=keep.device).unsqueeze(0) % counts
    return torch.gather(order, 1, position)


def plane_cut(points: Tensor, probability: float, generator: torch.Generator | None = None) -> Tensor:
    """Indices simulating a partial view: with `probability`, drop the points beyond a random plane (10-40%)."""
    b, n, _ = points.shape
    device = generator.device if generator is not None else points.device
    direction = torch.randn(b, 3, generator=generator, device=device).to(points)
    projection = ((points - points.mean(1, keepdim=True)) * direction.unsqueeze(1)).sum(-1)
    num_kept = ((0.6 + 0.3 * _uniform(b, points, generator)) * n).long().clamp_min(3)
    apply = (_uniform(b, points, generator) < probability).unsqueeze(1)
    return refill_indices(~apply | (_rank(projection) < num_kept.unsqueeze(1)), n, generator)


def ball_cut(points: Tensor, probability: float, generator: torch.Generator | None = None) -> Tensor:
    """Indices simulating an occluder: with `probability`, drop the 5-20% of points nearest a random point."""
    b, n, _ = points.shape
    device = generator.device if generator is not None else points.device
    centre_index = torch.randint(0, n, (b,), generator=generator, device=device).to(points.device)
    centre = points[torch.arange(b, device=points.device), centre_index].unsqueeze(1)
    distance = (points - centre).norm(dim=-1)
    num_removed = ((0.05 + 0.15 * _uniform(b, points, generator)) * n).long().clamp_min(1)
    apply = (_uniform(b, points, generator) < probability).unsqueeze(1)
    return refill_indices(~apply | (_rank(distance) >= num_removed.unsqueeze(1)), n, generator)


def downsample_indices(
    clouds: list[Tensor], num_points: list[int], generator: torch.Generator | None = None
) -> list[Tensor]:
    """Farthest point sampling of each cloud (B, N_i, 3) to `num_points[i]`, from a random start, so repeated
    epochs see different subsets; one FPS pass for all clouds. The indices come in selection order, so the
    clouds they pick are in FPS order from their point 0."""
    device = generator.device if generator is not None else clouds[0].device
    starts = [
        torch.randint(0, c.shape[1], (c.shape[0],), generator=generator, device=device).to(c.device) for c in clouds
    ]
    return farthest_point_sample_parts([c.float() for c in clouds], num_points, starts)
