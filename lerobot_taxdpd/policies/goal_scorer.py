"""A learned goal scorer: how likely a candidate goal cloud is to be executed successfully in its scene.

The goal predictor's K samples often hold a good goal that the first sample is not (book_shelf: a sample that
places in half the scenes, the first in a tenth). What tells them apart is contact geometry: does the book
stand on the shelf's floor between its neighbours or float, tilt or cut into them. So the scorer looks at each
candidate goal point together with its nearest scene points (their offsets, in object units, centred on the
candidate), a DP3-style per-point MLP pooled over the candidate, and a small head: one logit per candidate.
Nothing in it depends on where the scene is, and it is trained under random turns about the vertical.

A scorer can also move the goal it picks: with `search_extent_mm`, every sample is tried again shifted on a
horizontal grid around where it was sampled and the best-rated copy is executed. The samples of a predictor
scatter by about a slot's clearance along a shelf's row, which the scorer reads off the neighbours either side;
searching a few millimetres moves a good sample into its slot's centre rather than only choosing among them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from huggingface_hub import PyTorchModelHubMixin
from torch import Tensor, nn

from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import PointCloudEncoder, mlp


@dataclass
class GoalScorerConfig:
    #: Candidate points the scorer looks at (the first ones: recorded clouds are in FPS order).
    num_goal_points: int = 128
    #: Nearest scene points described around each candidate point.
    num_neighbors: int = 8
    hidden_dims: tuple[int, ...] = (64, 128, 256)
    feature_dim: int = 256
    #: Model units per metre: the training data's median object radius becomes 3, as in the goal predictor.
    point_scale: float = 1.0
    #: Also give each candidate point its offset from the same point of the start object (the rows of a goal
    #: cloud are the start cloud's points moved): how far, and which way, the executor must carry each part,
    #: which decides whether a deformable object gets there (a rigid one placed by a pose always does).
    start_displacement: bool = False
    #: Half the side of the horizontal grid of shifts each sample is also tried at (0: choose among the samples
    #: as sampled); chosen per task on held-out trials and shipped with the scorer, so a name brings its search.
    search_extent_mm: float = 0.0
    #: Spacing of that grid.
    search_step_mm: float = 3.0


#: Candidates scored at once while searching: bounds the (candidates, points, scene points) distance matrix.
SEARCH_BATCH = 64


class ScorerChoice(NamedTuple):
    """What the scorer executes: which sample, its cloud as executed, the shift it was moved by, and each
    sample's best score over its shifted copies (so the chosen one has the highest)."""

    index: int
    goal: Tensor  # (N, 3)
    shift: Tensor  # (3,), metres
    scores: Tensor  # (K,)


def search_shifts(extent_mm: float, step_mm: float) -> Tensor:
    """The horizontal grid (M, 3) of shifts in metres, no shift first: x and y from -extent to +extent."""
    if extent_mm < 0 or step_mm <= 0:
        raise ValueError(f"search grid: extent must be >= 0 and step > 0 (mm), got {extent_mm} and {step_mm}")
    half = int(extent_mm // step_mm)
    offsets = torch.arange(-half, half + 1, dtype=torch.float32) * step_mm / 1000
    grid = torch.cartesian_prod(offsets, offsets)
    grid = grid[torch.argsort(grid.norm(dim=1), stable=True)]  # the unshifted sample first, then nearest out
    return torch.cat([grid, torch.zeros(len(grid), 1)], 1)


class GoalScorer(nn.Module, PyTorchModelHubMixin, library_name="lerobot_taxdpd", tags=["goal-scorer"]):
    """Candidate goal clouds (B, N, 3) in their scenes (B, S, 3), metres -> success logits (B,)."""

    def __init__(self, config: GoalScorerConfig | dict | None = None) -> None:
        super().__init__()
        if isinstance(config, dict):  # as `from_pretrained` reads it back from config.json
            config = GoalScorerConfig(**{**config, "hidden_dims": tuple(config["hidden_dims"])})
        self.config = config or GoalScorerConfig()
        # the point, then each neighbour's offset and distance, then (optionally) its offset from the start
        channels = 3 + 4 * self.config.num_neighbors + 3 * self.config.start_displacement
        self.encoder = PointCloudEncoder(channels, self.config.hidden_dims, self.config.feature_dim)
        self.head = mlp(self.config.feature_dim, (128, 1))

    def point_features(self, goals: Tensor, scenes: Tensor, starts: Tensor | None = None) -> Tensor:
        """(B, n, 3 + 4k [+ 3]): each of the first n candidate points, centred and scaled, its k nearest scene
        points as offsets and distances, nearest first, and with `start_displacement` its offset from the same
        point of the start object `starts` (B, N, 3)."""
        config = self.config
        goals = goals[:, : config.num_goal_points]
        moved = None
        if config.start_displacement:
            if starts is None:
                raise ValueError("this scorer reads each point's offset from the start object: give the start cloud")
            moved = (goals - starts[:, : goals.shape[1]]) * config.point_scale
        centre = goals.mean(1, keepdim=True)
        goals, scenes = (goals - centre) * config.point_scale, (scenes - centre) * config.point_scale
        k = min(config.num_neighbors, scenes.shape[1])
        distances, index = torch.cdist(goals, scenes).topk(k, dim=-1, largest=False)
        neighbours = torch.gather(
            scenes.unsqueeze(1).expand(-1, goals.shape[1], -1, -1), 2, index.unsqueeze(-1).expand(-1, -1, -1, 3)
        )
        offsets = neighbours - goals.unsqueeze(2)
        features = torch.cat([offsets, distances.unsqueeze(-1)], -1).flatten(2)
        if k < config.num_neighbors:  # a scene smaller than k points: pad as if the rest were far away
            features = nn.functional.pad(features, (0, 4 * (config.num_neighbors - k)), value=10.0)
        return torch.cat([goals, features] + ([moved] if moved is not None else []), -1)

    def forward(self, goals: Tensor, scenes: Tensor, starts: Tensor | None = None) -> Tensor:
        return self.head(self.encoder(self.point_features(goals, scenes, starts))).squeeze(-1)

    @torch.no_grad()
    def score(self, samples: Tensor, scene: Tensor, start: Tensor | None = None) -> Tensor:
        """K samples (K, N, 3) of one scene (S, 3) and its start object (N, 3) -> their K logits."""
        starts = None if start is None else start.float().expand(len(samples), -1, -1)
        return self(samples.float(), scene.float().expand(len(samples), -1, -1), starts)

    @torch.no_grad()
    def choose(self, samples: Tensor, scene: Tensor, start: Tensor | None = None) -> ScorerChoice:
        """The goal to execute among K samples (K, N, 3) of one scene: the best-rated sample, or with
        `search_extent_mm` the best-rated of all samples' shifted copies (ties go to the earlier sample and
        the smaller shift)."""
        shifts = search_shifts(self.config.search_extent_mm, self.config.search_step_mm).to(samples.device)
        candidates = (samples.float()[:, None] + shifts[None, :, None]).flatten(0, 1)  # sample-major
        scores = [self.score(chunk, scene, start) for chunk in candidates.split(SEARCH_BATCH)]
        scores = torch.cat(scores).view(len(samples), len(shifts))
        best_shift = scores.argmax(1)
        per_sample = scores.max(1).values
        index = int(per_sample.argmax())
        shift = shifts[best_shift[index]]
        return ScorerChoice(index, samples[index] + shift.to(samples.dtype), shift, per_sample)
