"""PNG figures of an evaluation: a scene with its K sampled goals, and the Dense GMM's weight map.

Matplotlib with the Agg backend, so figures render headless. Each figure shows the same scene from an
oblique and a top view with equal axis scales (distorted axes hide exactly the errors that matter).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lerobot_taxdpd.sim.trials import Trial  # noqa: E402

VIEWS = ((25.0, -60.0), (89.0, -90.0))
SAMPLE_COLOURS = plt.cm.tab10([1, 3, 4, 5, 6, 8, 9])  # tab10 without the blue, green and grey used above


def _equal_axes(ax, points: np.ndarray) -> None:
    centre = (points.max(0) + points.min(0)) / 2
    radius = (points.max(0) - points.min(0)).max() / 2 * 1.05
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - radius, c + radius)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def plot_goal_samples(trial: Trial, samples: np.ndarray, path: Path, *, success: bool | None = None) -> Path:
    """Scene (grey), object at its start (blue), demonstrated goal (green) and the K samples (colours)."""
    fig = plt.figure(figsize=(12, 6))
    colours = SAMPLE_COLOURS[np.arange(len(samples)) % len(SAMPLE_COLOURS)]
    everything = np.concatenate([trial.scene_points, trial.object_points, *samples])
    for i, (elevation, azimuth) in enumerate(VIEWS):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.scatter(*trial.scene_points.T, s=1, c="0.6", label="scene")
        ax.scatter(*trial.object_points.T, s=1, c="tab:blue", label="object (start)")
        ax.scatter(*trial.goal_points().T, s=2, c="tab:green", alpha=0.4, label="ground-truth goal")
        for k, (sample, colour) in enumerate(zip(samples, colours)):
            ax.scatter(*sample.T, s=1, color=colour, alpha=0.7, label="samples" if k == 0 else None)
        _equal_axes(ax, everything)
        ax.view_init(elevation, azimuth)
    fig.axes[0].legend(loc="upper left", markerscale=6, fontsize=8)
    verdict = "" if success is None else (" - executed sample succeeded" if success else " - executed sample failed")
    fig.suptitle(f"{trial.task.name}, seed {trial.seed}: {len(samples)} sampled goals{verdict}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_weight_map(trial: Trial, weights: np.ndarray, means: np.ndarray, path: Path) -> Path:
    """Scene points coloured by their Dense-GMM weight (log scale), with the demo's goal centroid."""
    fig = plt.figure(figsize=(12, 6))
    order = np.argsort(weights)
    log_weights = np.log10(np.clip(weights, 1e-8, None))
    goal_centre = trial.goal_points().mean(0)
    for i, (elevation, azimuth) in enumerate(VIEWS):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        points = ax.scatter(
            *trial.scene_points[order].T,
            s=3,
            c=log_weights[order],
            cmap="viridis",
            vmin=log_weights.min(),
            vmax=max(log_weights.max(), log_weights.min() + 1e-3),
        )
        top = np.argsort(weights)[-10:]
        ax.scatter(*means[top].T, s=12, c="tab:red", marker="x", label="means of the 10 heaviest components")
        ax.scatter(*goal_centre, s=80, c="tab:green", marker="*", label="ground-truth goal centroid")
        _equal_axes(ax, np.concatenate([trial.scene_points, goal_centre[None]]))
        ax.view_init(elevation, azimuth)
    fig.colorbar(points, ax=fig.axes, shrink=0.6, label="log10 GMM weight")
    fig.axes[0].legend(loc="upper left", fontsize=8)
    fig.suptitle(f"{trial.task.name}, seed {trial.seed}: Dense GMM over the scene")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
