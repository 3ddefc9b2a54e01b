"""PointNet++ in plain PyTorch (no compiled extensions), split so that work can be cached.

A forward pass has three parts with different lifetimes:
- `SamplingLayout`: which points become set-abstraction centroids (farthest point sampling). It is
  computed per *part* (object, scene) from coordinates that do not change while denoising (the initial
  object, the scene), so one layout serves every encoder and every denoising step.
- `Grouping`: ball-query neighbours and 3-NN interpolation weights for the current coordinates. Cached
  when the coordinates are constant (object and deformation encoders), rebuilt each step otherwise.
- the MLPs, the only part with parameters.

Widths follow the paper's encoder at hidden size 128 and scale with `hidden_dim`: set abstraction
(64, 64, 128) and (128, 128, 256) with ratios 0.2 / 0.25 and at most 64 neighbours, a global layer
(256, 512, 1024), feature propagation back to `hidden_dim` per point, no batch norm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lerobot_taxdpd.maths.geometry import farthest_point_sample_parts, gather_points, takes_cpu_shortcuts


@dataclass
class SamplingLayout:
    """Centroid indices: level 1 into the points, level 2 into the level-1 centroids."""

    level1: Tensor  # (B, M1)
    level2: Tensor  # (B, M2)

    def repeat_interleave(self, repeats: int) -> SamplingLayout:
        if repeats == 1:
            return self
        return SamplingLayout(self.level1.repeat_interleave(repeats, 0), self.level2.repeat_interleave(repeats, 0))

    def head(self, n: int) -> SamplingLayout:
        """The layout of the first `n` clouds of the batch."""
        return SamplingLayout(self.level1[:n], self.level2[:n])


@dataclass
class Grouping:
    """What a PointNet++ pass derives from the coordinates alone: the centroids of both levels, their
    ball-query neighbourhoods and the 3-NN interpolation weights back down. Built in fp32; `cast` gives the
    coordinates and weights the layers' dtype once for a grouping that many passes reuse."""

    centres1: Tensor  # (B, M1, 3) level-1 centroids
    centres2: Tensor  # (B, M2, 3) level-2 centroids
    neighbors1: Tensor  # (B, M1, K) indices into the points
    neighbors2: Tensor  # (B, M2, K) indices into the level-1 centroids
    to_level1: tuple[Tensor, Tensor]  # 3-NN (indices into level 2, weights) for each level-1 centroid
    to_points: tuple[Tensor, Tensor]  # 3-NN (indices into level 1, weights) for each point

    def _map(self, coordinates, indices) -> Grouping:
        return Grouping(
            coordinates(self.centres1),
            coordinates(self.centres2),
            indices(self.neighbors1),
            indices(self.neighbors2),
            (indices(self.to_level1[0]), coordinates(self.to_level1[1])),
            (indices(self.to_points[0]), coordinates(self.to_points[1])),
        )

    def repeat_interleave(self, repeats: int) -> Grouping:
        def rep(x: Tensor) -> Tensor:
            return x.repeat_interleave(repeats, 0)

        return self if repeats == 1 else self._map(rep, rep)

    def head(self, n: int) -> Grouping:
        """The grouping of the first `n` clouds of the batch."""
        return self._map(lambda x: x[:n], lambda x: x[:n])

    def cast(self, dtype: torch.dtype) -> Grouping:
        """The centroids and interpolation weights in `dtype` (what the layers would cast them to each pass)."""
        return self._map(lambda x: x.to(dtype), lambda x: x)


def centroid_count(n: int, ratio: float) -> int:
    return max(1, round(n * ratio))


def _first_indices(batch: int, count: int, device: torch.device) -> Tensor:
    return torch.arange(count, device=device).expand(batch, count)


@torch.no_grad()
def part_layouts(
    parts: Sequence[Tensor], ratios: tuple[float, float], fps_ordered: Sequence[bool] | None = None
) -> list[SamplingLayout]:
    """FPS centroids of each part (B, N_i, 3) on its own, indexed into that part.

    FPS of a prefix of an FPS order, from its first point, is that prefix again (each next point of the order is
    the farthest of the whole cloud, so of any prefix holding it). So level 2, the FPS of the level-1 centroids,
    is their first points, and a part already in FPS order from its point 0 (`fps_ordered[i]`: the policy's own
    downsampling made it) needs no FPS at all. The others share one FPS pass (`farthest_point_sample_parts`)."""
    parts = [part.float() for part in parts]
    fps_ordered = fps_ordered if fps_ordered is not None else [False] * len(parts)
    counts1 = [centroid_count(part.shape[1], ratios[0]) for part in parts]
    todo = [i for i, ordered in enumerate(fps_ordered) if not ordered]
    sampled = iter(farthest_point_sample_parts([parts[i] for i in todo], [counts1[i] for i in todo]) if todo else [])
    b, device = parts[0].shape[0], parts[0].device
    return [
        SamplingLayout(
            _first_indices(b, count1, device) if ordered else next(sampled),
            _first_indices(b, centroid_count(count1, ratios[1]), device),
        )
        for ordered, count1 in zip(fps_ordered, counts1, strict=True)
    ]


def concat_layouts(layouts: Sequence[SamplingLayout], sizes: Sequence[int]) -> SamplingLayout:
    """The layout of the concatenated parts (`sizes[i]` points each), from each part's own layout."""
    level1, level2 = [], []
    offset = offset1 = 0
    for layout, size in zip(layouts, sizes, strict=True):
        level1.append(layout.level1 + offset)
        level2.append(layout.level2 + offset1)
        offset += size
        offset1 += layout.level1.shape[1]
    return SamplingLayout(torch.cat(level1, 1), torch.cat(level2, 1))


def cloud_layouts(
    config, clouds: Sequence[Tensor], fps_ordered: Sequence[bool] | None = None
) -> list[SamplingLayout] | None:
    """The layouts of the model's clouds (the object, the scene, the local stage's scenes), which every PointNet++
    encoder shares (FPS does not change when a cloud moves rigidly), in one FPS pass, or None for the MLP
    encoders. `fps_ordered[i]`: cloud i is in FPS order from its point 0 already (see `part_layouts`)."""
    if config.encoder != "pointnet2":
        return None
    return part_layouts(clouds, config.sa_ratios, fps_ordered)


def sampling_layout(parts: Sequence[Tensor], ratios: tuple[float, float]) -> SamplingLayout:
    """FPS centroids per part (each (B, N_i, 3)), indexed into the concatenation of the parts."""
    return concat_layouts(part_layouts(parts, ratios), [part.shape[1] for part in parts])


def _distances(a: Tensor, b: Tensor) -> Tensor:
    """Euclidean distances (B, P, R) between points a (B, P, 3) and b (B, R, 3) in one kernel: the expansion
    |a|^2 + |b|^2 - 2 a.b through a matrix product takes nine launches and rounds near-zero distances worse."""
    return torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist")


def _ball_query(centres: Tensor, points: Tensor, radius: float, max_neighbors: int) -> Tensor:
    """Up to `max_neighbors` nearest points within `radius` of each centre; out-of-ball slots repeat the nearest."""
    dist, idx = _distances(centres, points).topk(min(max_neighbors, points.shape[1]), dim=-1, largest=False)
    return torch.where(dist <= radius, idx, idx[..., :1])


def _three_nn(targets: Tensor, sources: Tensor) -> tuple[Tensor, Tensor]:
    """Inverse-square-distance weights of the 3 nearest sources of every target."""
    dist, idx = _distances(targets, sources).topk(min(3, sources.shape[1]), dim=-1, largest=False)
    weights = dist.square().add_(1e-8).reciprocal_()
    return idx, weights / weights.sum(-1, keepdim=True)


@torch.no_grad()
def build_grouping(xyz: Tensor, layout: SamplingLayout, radii: tuple[float, float], max_neighbors: int) -> Grouping:
    """Neighbourhoods and interpolation weights of `xyz` (B, N, 3) for a fixed centroid layout (fp32)."""
    with torch.autocast(device_type=xyz.device.type, enabled=False):
        xyz = xyz.float()
        centres1 = gather_points(xyz, layout.level1)
        centres2 = gather_points(centres1, layout.level2)
        return Grouping(
            centres1=centres1,
            centres2=centres2,
            neighbors1=_ball_query(centres1, xyz, radii[0], max_neighbors),
            neighbors2=_ball_query(centres2, centres1, radii[1], max_neighbors),
            to_level1=_three_nn(centres1, centres2),
            to_points=_three_nn(xyz, centres1),
        )


def interpolate(features: Tensor, weights: tuple[Tensor, Tensor]) -> Tensor:
    """Values at every point from values (B, M1, C) at its 3 nearest centroids (inverse-square-distance weights).
    Off the CPU the weighted sum is one batched product (B, N, 1, 3) @ (B, N, 3, C), one launch instead of two;
    the CPU runs such tiny products 3-4 times slower than a product and a sum, so it keeps those."""
    idx, w = weights
    neighbours, w = gather_points(features, idx), w.to(features.dtype)
    if takes_cpu_shortcuts(features):
        return (neighbours * w.unsqueeze(-1)).sum(-2)
    return (w.unsqueeze(-2) @ neighbours).squeeze(-2)


def _mlp(widths: Sequence[int], final_activation: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if final_activation or i < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class SetAbstraction(nn.Module):
    """Shared MLP on [p_j - c_i, f_j] over each ball, max-pooled.

    The first layer is linear in (p_j - c_i), so it is evaluated once per point and once per centroid
    (W_x p_j + W_f f_j + b, minus W_x c_i) instead of once per (centroid, neighbour) pair. The last ReLU is
    applied after the pooling (max and ReLU commute), and the pooling keeps its argmax so that its backward
    writes one value per ball instead of comparing every (centroid, neighbour) pair: the largest tensors of
    the step, (B, M, K, C), pass through two fewer elementwise ops each way.
    """

    def __init__(self, in_channels: int, widths: Sequence[int]) -> None:
        super().__init__()
        self.first = nn.Linear(in_channels + 3, widths[0])
        self.rest = _mlp(widths, final_activation=False)

    def forward(self, xyz: Tensor, features: Tensor, centres_xyz: Tensor, neighbors: Tensor) -> Tensor:
        per_point = self.first(torch.cat([xyz, features], -1))
        per_centre = F.linear(centres_xyz, self.first.weight[:, :3])
        grouped = gather_points(per_point, neighbors) - per_centre.unsqueeze(-2).to(per_point.dtype)
        return torch.relu(self.rest(torch.relu_(grouped)).max(dim=-2).values)


class PointNet2Encoder(nn.Module):
    """Per-point features (B, N, out_dim) of a cloud with extra per-point input channels."""

    def __init__(
        self,
        in_channels: int,
        out_dim: int,
        hidden_dim: int,
        ratios: tuple[float, float],
        radii: tuple[float, float],
        max_neighbors: int,
    ) -> None:
        super().__init__()
        b = max(hidden_dim // 2, 8)
        self.ratios, self.radii, self.max_neighbors = ratios, radii, max_neighbors
        self.sa1 = SetAbstraction(in_channels + 3, (b, b, 2 * b))
        self.sa2 = SetAbstraction(2 * b, (2 * b, 2 * b, 4 * b))
        self.global_sa = _mlp((4 * b + 3, 4 * b, 8 * b, 16 * b))
        self.fp_global = _mlp((16 * b + 4 * b, 4 * b, 4 * b))
        self.fp2 = _mlp((4 * b + 2 * b, 4 * b, 2 * b))
        self.fp1 = _mlp((2 * b + in_channels + 3, 2 * b, 2 * b, out_dim), final_activation=False)

    def layout(self, parts: Sequence[Tensor]) -> SamplingLayout:
        """Centroids chosen per part (e.g. [object, scene]) of the concatenated cloud."""
        return sampling_layout(parts, self.ratios)

    def compute_dtype(self, xyz: Tensor) -> torch.dtype:
        """The dtype the linear layers compute in: autocast's where it is on, else the weights'."""
        if torch.is_autocast_enabled(xyz.device.type):
            return torch.get_autocast_dtype(xyz.device.type)
        return self.sa1.first.weight.dtype

    def group(self, xyz: Tensor, layout: SamplingLayout) -> Grouping:
        return build_grouping(xyz, layout, self.radii, self.max_neighbors)

    def forward(
        self, xyz: Tensor, features: Tensor, layout: SamplingLayout | None = None, grouping: Grouping | None = None
    ) -> Tensor:
        if grouping is None:
            grouping = self.group(xyz, layout if layout is not None else self.layout([xyz]))  # fp32
        # The layers compute in one dtype (bf16 under autocast): the coordinates are cast to it once, here, so
        # that no concatenation of coordinates with features promotes and casts back, at no change of value.
        dtype = self.compute_dtype(xyz)
        point_features = torch.cat([xyz, features], -1).to(dtype)
        xyz = point_features[..., :3]
        centres1, centres2 = grouping.centres1.to(dtype), grouping.centres2.to(dtype)
        f1 = self.sa1(xyz, point_features, centres1, grouping.neighbors1)
        f2 = self.sa2(centres1, f1, centres2, grouping.neighbors2)
        global_feature = self.global_sa(torch.cat([centres2, f2], -1)).amax(dim=1, keepdim=True)
        f2 = self.fp_global(torch.cat([f2, global_feature.expand(-1, f2.shape[1], -1)], -1))
        f1 = self.fp2(torch.cat([interpolate(f2, grouping.to_level1), f1], -1))
        return self.fp1(torch.cat([interpolate(f1, grouping.to_points), point_features], -1))


class PointMLPEncoder(nn.Module):
    """The "w/ MLP encodings" ablation: the same per-point interface with no neighbourhood reasoning."""

    def __init__(self, in_channels: int, out_dim: int, hidden_dim: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(in_channels + 3, hidden_dim),
            nn.LayerNorm(hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.LayerNorm(hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, out_dim),
        )

    def layout(self, parts: Sequence[Tensor]) -> None:
        return None

    def group(self, xyz: Tensor, layout: SamplingLayout | None) -> None:
        return None

    def forward(self, xyz: Tensor, features: Tensor, layout=None, grouping=None) -> Tensor:
        return self.net(torch.cat([xyz, features], -1))


def make_encoder(config, in_channels: int) -> PointNet2Encoder | PointMLPEncoder:
    """The encoder selected by `config.encoder`, taking xyz plus `in_channels` extra channels per point."""
    if config.encoder == "mlp":
        return PointMLPEncoder(in_channels, config.hidden_dim, config.hidden_dim)
    return PointNet2Encoder(
        in_channels, config.hidden_dim, config.hidden_dim, config.sa_ratios, config.sa_radii, config.max_neighbors
    )
