"""Training a goal scorer on a collection (`scoring.collect`): which of a scene's K samples to execute.

Two terms per scene of a batch, all K samples together: a per-sample success logit (binary cross-entropy),
and, in scenes where some samples succeeded, a softmax over the K that puts the mass on those (the choice the
scorer is used for). Every scene is turned by a random angle about the vertical (gravity stays down). A tenth
of the collection's scenes, the last seeds, is held back to report what choosing by the score does there
beside the first sample and the best a perfect chooser could do.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F

from lerobot_taxdpd.data.scaling import object_radius
from lerobot_taxdpd.data.schema import METRICS_FILE
from lerobot_taxdpd.policies.goal_scorer import GoalScorer, GoalScorerConfig
from lerobot_taxdpd.scoring.collect import load_collection


def _turned(points: Tensor, angles: Tensor) -> Tensor:
    """Each batch row (B, ..., 3) turned about the vertical by its angle."""
    cos, sin = angles.cos(), angles.sin()
    shape = (-1,) + (1,) * (points.dim() - 2)
    x, y = points[..., 0], points[..., 1]
    c, s = cos.view(shape), sin.view(shape)
    return torch.stack([c * x - s * y, s * x + c * y, points[..., 2]], -1)


def scene_losses(
    scorer: GoalScorer, samples: Tensor, scenes: Tensor, success: Tensor, starts: Tensor | None = None
) -> Tensor:
    """Scenes (B, S, 3), their K samples (B, K, N, 3), outcomes (B, K) and start objects (B, N, 3) -> the loss."""
    batch, k = success.shape
    starts = None if starts is None else starts.repeat_interleave(k, 0)
    logits = scorer(samples.flatten(0, 1), scenes.repeat_interleave(k, 0), starts).view(batch, k)
    target = success.float()
    per_sample = F.binary_cross_entropy_with_logits(logits, target)
    solvable = target.sum(1) > 0
    choice = -(torch.log_softmax(logits, 1) * target / target.sum(1, keepdim=True).clamp_min(1)).sum(1)
    return per_sample + (choice * solvable).sum() / solvable.sum().clamp_min(1)


def seed_runs(seeds) -> str:
    """Sorted seeds as their runs of consecutive ones, "5000..5129, 5300..5419" (a collection made in legs or
    by several processes can leave gaps)."""
    seeds = sorted(int(seed) for seed in seeds)
    runs, start = [], seeds[0]
    for previous, seed in zip(seeds, [*seeds[1:], None], strict=True):
        if seed is None or seed != previous + 1:
            runs.append(f"{start}..{previous}")
            start = seed
    return ", ".join(runs)


def choice_rates(scores: np.ndarray, success: np.ndarray) -> dict[str, float]:
    """Success of executing the highest-scored sample of each scene, the first, and the best possible; and the
    share of (successful, failed) sample pairs of one scene that the scores order right (ties count half, so
    0.5 is chance), which rests on every pair rather than on one choice a scene and so varies less."""
    picked = success[np.arange(len(success)), scores.argmax(1)]
    right = pairs = 0.0
    for row_scores, row_success in zip(scores, success.astype(bool), strict=True):
        difference = row_scores[row_success][:, None] - row_scores[~row_success][None, :]
        right += (difference > 0).sum() + 0.5 * (difference == 0).sum()
        pairs += difference.size
    return {
        "scorer": float(picked.mean()),
        "first_sample": float(success[:, 0].mean()),
        "any_sample": float(success.any(1).mean()),
        "scenes": len(success),
        "pairs_ordered": float(right / pairs) if pairs else float("nan"),
        "pairs": int(pairs),
    }


def fit_scorer(
    data: dict[str, np.ndarray],
    train_rows: np.ndarray,
    *,
    steps: int = 2000,
    batch_scenes: int = 8,
    learning_rate: float = 1e-3,
    seed: int = 0,
    config: GoalScorerConfig | None = None,
) -> tuple[GoalScorer, list[float]]:
    """A scorer (eval mode) trained on the scenes `train_rows` of a loaded collection, and its losses."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    radius = float(object_radius(torch.from_numpy(data["object"])).median())
    config = config or GoalScorerConfig()
    config.point_scale = 3.0 / radius  # as the goal predictor: the median object radius is 3 model units
    scorer = GoalScorer(config)
    optimizer = torch.optim.AdamW(scorer.parameters(), lr=learning_rate, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: 0.5 * (1 + math.cos(math.pi * step / steps)))
    tensors = _candidate_tensors(data, config)
    losses = []
    scorer.train()
    for _ in range(steps):
        rows = torch.from_numpy(rng.choice(train_rows, size=min(batch_scenes, len(train_rows)), replace=False))
        angles = torch.from_numpy(rng.uniform(-math.pi, math.pi, len(rows))).float()
        loss = scene_losses(
            scorer,
            _turned(tensors["samples"][rows], angles),
            _turned(tensors["scene"][rows], angles),
            tensors["success"][rows],
            _turned(tensors["object"][rows], angles),
        )
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        schedule.step()
        losses.append(loss.item())
    return scorer.eval(), losses


def score_scenes(scorer: GoalScorer, data: dict[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
    """The scorer's logits (len(rows), K) for the K samples of each of these scenes of a loaded collection."""
    tensors = _candidate_tensors(data, scorer.config)
    return np.stack(
        [scorer.score(tensors["samples"][i], tensors["scene"][i], tensors["object"][i]).numpy() for i in rows]
    )


def _candidate_tensors(data: dict[str, np.ndarray], config: GoalScorerConfig) -> dict[str, Tensor]:
    """Scenes, outcomes and the candidate points the scorer looks at (only those are turned in every step)."""
    return {
        "scene": torch.from_numpy(data["scene"]),
        "samples": torch.from_numpy(data["samples"][:, :, : config.num_goal_points]),
        "object": torch.from_numpy(data["object"][:, : config.num_goal_points]),
        "success": torch.from_numpy(data["success"]),
    }


def train_scorer(
    collection: Path,
    output: Path,
    *,
    steps: int = 2000,
    batch_scenes: int = 8,
    learning_rate: float = 1e-3,
    validation_fraction: float = 0.1,
    seed: int = 0,
    config: GoalScorerConfig | None = None,
) -> dict:
    """Train, report on the held-back scenes, and save the scorer (config, weights, metrics) in `output`."""
    details, data = load_collection(collection)
    scenes = len(data["seed"])
    held = max(1, round(scenes * validation_fraction)) if scenes > 1 else 0
    if scenes - held < 1:
        raise ValueError(f"{collection}: {scenes} scenes; a scorer needs at least 2 (one to train, one to check)")
    started = time.perf_counter()
    scorer, losses = fit_scorer(
        data, np.arange(scenes - held), steps=steps, batch_scenes=batch_scenes, learning_rate=learning_rate,
        seed=seed, config=config,
    )  # fmt: skip
    config = scorer.config
    validation = {}
    if held:
        rows = np.arange(scenes - held, scenes)
        validation = choice_rates(score_scenes(scorer, data, rows), data["success"][rows])
    metrics = {
        "collection": details,
        "training_scenes": int(scenes - held),
        "training_seeds": seed_runs(data["seed"][: scenes - held]),
        "collected_seeds": seed_runs(data["seed"]),
        "steps": steps,
        "seed": seed,
        "batch_scenes": batch_scenes,
        "num_goal_points": config.num_goal_points,
        "start_displacement": config.start_displacement,
        "search_extent_mm": config.search_extent_mm,
        "search_step_mm": config.search_step_mm,
        "train_seconds": time.perf_counter() - started,
        "final_loss": float(np.mean(losses[-50:])),
        "held_back_scenes": validation,
        "label_success_rate": float(data["success"].mean()),
    }
    output = Path(output)
    scorer.save_pretrained(output)
    (output / METRICS_FILE).write_text(json.dumps(metrics, indent=2))
    return metrics
