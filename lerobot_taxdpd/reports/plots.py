"""PNG figures of goal predictions: sampled goal clouds in their scene, and the Dense GMM's weight map.

One set of figures for every caller (the simulation harness, the synthetic demo): plain arrays in metres.
Matplotlib with the Agg backend, so figures render headless. Each figure shows the scene from an oblique
and a top view with equal axis scales (distorted axes hide exactly the errors that matter).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

VIEWS = ((25.0, -60.0), (89.0, -90.0))
SAMPLE_COLOURS = plt.cm.tab10([1, 3, 4, 5, 6, 8, 9])  # tab10 without the blue, green and grey used below


def _equal_axes(ax, points: np.ndarray) -> None:
    centre = (points.max(0) + points.min(0)) / 2
    radius = (points.max(0) - points.min(0)).max() / 2 * 1.05
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(c - radius, c + radius)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_goal_samples(
    path: str | Path,
    scene_points: np.ndarray,
    object_points: np.ndarray,
    samples: np.ndarray,
    *,
    valid_goals: Sequence[np.ndarray] = (),
    goals_label: str = "valid goals",
    title: str = "",
) -> Path:
    """Scene (grey), object at its start (blue), valid goals (green) and the K sampled goals (colours).

    `goals_label` names the green clouds in the legend, e.g. "ground-truth goal" for a demonstration's.
    """
    fig = plt.figure(figsize=(12, 6))
    colours = SAMPLE_COLOURS[np.arange(len(samples)) % len(SAMPLE_COLOURS)]
    everything = np.concatenate([scene_points, object_points, *samples, *valid_goals])
    for i, (elevation, azimuth) in enumerate(VIEWS):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.scatter(*scene_points.T, s=1, c="0.6", label="scene")
        ax.scatter(*object_points.T, s=1, c="tab:blue", label="object (start)")
        for g, goal in enumerate(valid_goals):
            ax.scatter(*goal.T, s=2, c="tab:green", alpha=0.35, label=goals_label if g == 0 else None)
        for k, (sample, colour) in enumerate(zip(samples, colours, strict=True)):
            ax.scatter(*sample.T, s=1, color=colour, alpha=0.7, label="sampled goals" if k == 0 else None)
        _equal_axes(ax, everything)
        ax.view_init(elevation, azimuth)
    fig.axes[0].legend(loc="upper left", markerscale=6, fontsize=8)
    fig.suptitle(title or f"{len(samples)} sampled goals")
    fig.tight_layout()
    return _save(fig, path)


def plot_weight_map(
    path: str | Path,
    scene_points: np.ndarray,
    weights: np.ndarray,
    means: np.ndarray,
    *,
    goal_centroids: np.ndarray | None = None,
    centroids_label: str = "valid goal centroids",
    title: str = "",
) -> Path:
    """Scene points coloured by their Dense-GMM weight (log scale), the heaviest means and the true goal(s)."""
    fig = plt.figure(figsize=(12, 6))
    order = np.argsort(weights)
    log_weights = np.log10(np.clip(weights, 1e-8, None))
    marks = np.zeros((0, 3)) if goal_centroids is None else np.atleast_2d(goal_centroids)
    for i, (elevation, azimuth) in enumerate(VIEWS):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        points = ax.scatter(
            *scene_points[order].T,
            s=3,
            c=log_weights[order],
            cmap="viridis",
            vmin=log_weights.min(),
            vmax=max(log_weights.max(), log_weights.min() + 1e-3),  # a flat map still gets a colour bar
        )
        top = order[-10:]
        ax.scatter(*means[top].T, s=12, c="tab:red", marker="x", label="means of the 10 heaviest components")
        if len(marks):
            ax.scatter(*marks.T, s=80, c="tab:green", marker="*", label=centroids_label)
        _equal_axes(ax, np.concatenate([scene_points, marks]))
        ax.view_init(elevation, azimuth)
    fig.colorbar(points, ax=fig.axes, shrink=0.6, label="log10 GMM weight")
    fig.axes[0].legend(loc="upper left", fontsize=8)
    fig.suptitle(title or "Dense GMM over the scene")
    return _save(fig, path)
