"""The encoders' set-abstraction centres skip farthest point sampling where its answer is known: level 2 is the
first level-1 centres, and a cloud the policy reduced by FPS itself is its own layout. Both shortcuts must give
the centres that running FPS gives."""

from __future__ import annotations

import contextlib

import pytest
import torch

from lerobot_taxdpd.maths import geometry
from lerobot_taxdpd.maths.geometry import (
    device_code_paths,
    farthest_point_sample,
    farthest_point_sample_parts,
    gather_points,
)
from lerobot_taxdpd.policies.taxdpd.augmentation import downsample_indices
from lerobot_taxdpd.policies.taxdpd.model.pointnet2 import centroid_count, part_layouts
from lerobot_taxdpd.reports.launches import LaunchCounter

RATIOS = (0.2, 0.25)


def fps_layout(cloud: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The layout by definition: FPS of the cloud, then FPS of the centres it picked (both from point 0)."""
    level1 = farthest_point_sample(cloud, centroid_count(cloud.shape[1], RATIOS[0]))
    centres = gather_points(cloud, level1)
    return level1, farthest_point_sample(centres, centroid_count(level1.shape[1], RATIOS[1]))


def clouds(seed: int) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(3, 200, 3, generator=g) * torch.tensor([0.3, 0.1, 0.05]), torch.rand(3, 500, 3, generator=g)]


@pytest.mark.parametrize("seed", range(3))
def test_level_two_of_the_layout_is_the_fps_of_the_level_one_centres(seed):
    parts = clouds(seed)
    for part, layout in zip(parts, part_layouts(parts, RATIOS), strict=True):
        level1, level2 = fps_layout(part)
        assert torch.equal(layout.level1, level1)
        assert torch.equal(layout.level2, level2)


@pytest.mark.parametrize("device_path", [False, True], ids=["cpu", "device"])
def test_a_cloud_reduced_by_fps_is_its_own_layout(device_path):
    """The training augmentation's reduction leaves clouds in FPS order: their layout (free) equals FPS's."""
    torch.manual_seed(0)
    parts = clouds(3)
    with device_code_paths() if device_path else contextlib.nullcontext():
        keeps = downsample_indices(parts, [64, 128])
        reduced = [gather_points(part, keep) for part, keep in zip(parts, keeps, strict=True)]
        free = part_layouts(reduced, RATIOS, fps_ordered=[True, True])
    for cloud, layout in zip(reduced, free, strict=True):
        level1, level2 = fps_layout(cloud)
        assert torch.equal(layout.level1, level1)
        assert torch.equal(layout.level2, level2)
    counter = LaunchCounter()
    with device_code_paths(), counter:
        part_layouts(reduced, RATIOS, fps_ordered=[True, True])
    assert counter.total_ops() <= 4  # the index ranges only: no FPS loop


def test_fps_of_several_clouds_in_one_pass_matches_each_on_its_own():
    parts = clouds(4)
    starts = [torch.tensor([0, 7, 199]), torch.tensor([3, 499, 250])]
    alone = [farthest_point_sample(p, n, s) for p, n, s in zip(parts, [30, 90], starts, strict=True)]
    with device_code_paths():
        together = farthest_point_sample_parts(parts, [30, 90], starts)
    for a, b in zip(alone, together, strict=True):
        assert torch.equal(a, b)
    assert [chosen[:, 0].tolist() for chosen in together] == [s.tolist() for s in starts]


def test_the_device_loop_with_its_distance_table_picks_what_it_picks_row_by_row(monkeypatch):
    clouds = torch.rand(4, 700, 3, generator=torch.Generator().manual_seed(5))
    starts = torch.tensor([0, 1, 350, 699])
    with device_code_paths():
        with_table = farthest_point_sample(clouds, 150, starts)
        monkeypatch.setattr(geometry, "FPS_DISTANCE_TABLE_BYTES", 0)
        row_by_row = farthest_point_sample(clouds, 150, starts)
    assert torch.equal(with_table, row_by_row)
    exact = farthest_point_sample(clouds, 150, starts)  # fpsample's, on the CPU: the same points, in an order
    for ours, theirs in zip(with_table, exact, strict=True):  # that may swap at float near-ties
        assert set(ours.tolist()) == set(theirs.tolist())
