"""PNG figures of goal predictions: sampled goal clouds in their scene, and the Dense GMM's weight map.

One set of figures for every caller (the simulation harness, the cloth evaluation, the synthetic demo):
plain arrays in metres. Matplotlib with the Agg backend, so figures render headless. Each figure shows the
scene from an oblique 3-D view and in a 2-D top view, both with equal axis scales (distorted axes hide
exactly the errors that matter), framed on the scene, the object and the valid goals: a sample that lands
far away is named in the legend instead of shrinking everything else to a dot. Every sample has its own
colour, legend entry and number (at its centroid), sample 1 being the one a harness executes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import patheffects  # noqa: E402

OBLIQUE_VIEW = (25.0, -60.0)  # elevation, azimuth (degrees)
#: tab20 without the blues, greens and greys used for the object, the valid goals and the scene; the seven
#: strong hues first, then their light versions.
SAMPLE_COLOURS = plt.cm.tab20([2, 6, 8, 10, 12, 16, 18, 3, 7, 9, 11, 13, 17, 19])
MARGIN = 0.1  # of the framed extent, on every side
NUMBER_STYLE = dict(
    fontsize=9, fontweight="bold", path_effects=[patheffects.withStroke(linewidth=2.5, foreground="white")]
)


def _frame(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and half-width of a cube holding `points` with a margin."""
    centre = (points.max(0) + points.min(0)) / 2
    return centre, max((points.max(0) - points.min(0)).max() / 2 * (1 + 2 * MARGIN), 1e-3)


def _axes(fig, centre: np.ndarray, half: float):
    """An oblique 3-D view and a 2-D top view of the same cube, equal scales, labelled in metres."""
    oblique = fig.add_subplot(1, 2, 1, projection="3d")
    for setter, c in zip((oblique.set_xlim, oblique.set_ylim, oblique.set_zlim), centre, strict=True):
        setter(c - half, c + half)
    oblique.set_box_aspect((1, 1, 1))
    oblique.view_init(*OBLIQUE_VIEW)
    oblique.set(xlabel="x (m)", ylabel="y (m)", zlabel="z (m)", title="oblique view")
    oblique.locator_params(nbins=5)
    top = fig.add_subplot(1, 2, 2)
    top.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half))
    top.set_aspect("equal")
    top.set(xlabel="x (m)", ylabel="y (m)", title="top view")
    top.locator_params(nbins=6)
    top.grid(alpha=0.3)
    return oblique, top


def _scatter(oblique, top, points: np.ndarray, **style) -> None:
    """The same points in both views, clipped to the framed cube (3-D axes do not clip), the top view drawn in
    height order so that upper points stay visible."""
    (x0, x1), (y0, y1), (z0, z1) = oblique.get_xlim(), oblique.get_ylim(), oblique.get_zlim()
    low, high = np.array([x0, y0, z0]), np.array([x1, y1, z1])
    points = points[np.all((points >= low) & (points <= high), axis=1)]
    oblique.scatter(*points.T, **style)
    order = np.argsort(points[:, 2])
    top.scatter(*points[order, :2].T, **{key: value for key, value in style.items() if key != "label"})


def _inside(point: np.ndarray, centre: np.ndarray, half: float) -> bool:
    return bool(np.all(np.abs(point - centre) <= half))


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
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
    first_sample_label: str = "executed",
    scene_label: str = "scene",
    object_label: str = "object (start)",
    title: str = "",
) -> Path:
    """Scene (grey), object at its start (blue), valid goals (green) and the K sampled goals (numbered colours).

    The labels name what is drawn in the legend: `goals_label` the green clouds (e.g. "ground-truth goal" for
    a demonstration's), `first_sample_label` what sample 1 is (empty: nothing), `scene_label` and
    `object_label` the scene and the object (e.g. "hangers", "cloth (start)").
    """
    centre, half = _frame(np.concatenate([scene_points, object_points, *valid_goals]))
    fig = plt.figure(figsize=(14, 6.5))
    oblique, top = _axes(fig, centre, half)
    _scatter(oblique, top, scene_points, s=1, c="0.6", label=scene_label)
    _scatter(oblique, top, object_points, s=1, c="tab:blue", label=object_label)
    for g, goal in enumerate(valid_goals):
        _scatter(oblique, top, goal, s=2, c="tab:green", alpha=0.35, label=goals_label if g == 0 else None)
    outside = []
    for k, sample in enumerate(samples):
        colour = SAMPLE_COLOURS[k % len(SAMPLE_COLOURS)]
        label = f"sample {k + 1}" + (f" ({first_sample_label})" if k == 0 and first_sample_label else "")
        centroid = sample.mean(0)
        if _inside(centroid, centre, half):
            oblique.text(*centroid, str(k + 1), color=colour, **NUMBER_STYLE)
            top.annotate(str(k + 1), centroid[:2], color=colour, **NUMBER_STYLE)
        else:
            outside.append(k + 1)
            label += ", outside the view"
        _scatter(oblique, top, sample, s=1, color=colour, alpha=0.7, label=label)
    fig.legend(loc="center right", markerscale=6, fontsize=8, frameon=False)
    suffix = f" ({len(outside)} outside the view: {', '.join(map(str, outside))})" if outside else ""
    fig.suptitle((title or f"{len(samples)} sampled goals") + suffix)
    fig.subplots_adjust(left=0.02, right=0.82, wspace=0.15)
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
    marks = np.zeros((0, 3)) if goal_centroids is None else np.atleast_2d(goal_centroids)
    centre, half = _frame(np.concatenate([scene_points, marks]))
    fig = plt.figure(figsize=(14, 6.5))
    oblique, top = _axes(fig, centre, half)
    order = np.argsort(weights)  # heaviest drawn last, on top
    log_weights = np.log10(np.clip(weights, 1e-8, None))
    colours = dict(
        c=log_weights[order],
        cmap="viridis",
        vmin=log_weights.min(),
        vmax=max(log_weights.max(), log_weights.min() + 1e-3),  # a flat map still gets a colour bar
    )
    points = oblique.scatter(*scene_points[order].T, s=3, **colours)
    top.scatter(*scene_points[order, :2].T, s=3, **colours)
    heaviest = order[-10:]
    _scatter(oblique, top, means[heaviest], s=14, c="tab:red", marker="x", label="means of the 10 heaviest components")
    if len(marks):
        _scatter(oblique, top, marks, s=90, c="tab:green", marker="*", label=centroids_label)
    fig.subplots_adjust(left=0.02, right=0.86, wspace=0.25)
    fig.colorbar(points, cax=fig.add_axes((0.89, 0.25, 0.012, 0.5)), label="log10 GMM weight of a scene point")
    fig.legend(loc="lower center", fontsize=8, frameon=False, ncol=2)
    fig.suptitle(title or "Dense GMM over the scene")
    return _save(fig, path)
