"""PNG of one evaluation trial: hangers, the cloth at the start, the valid goals and the predicted goal."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np


def plot_trial(
    path: Path,
    hangers: np.ndarray,
    cloth: np.ndarray,
    valid_goals: Sequence[np.ndarray],
    predicted_goal: np.ndarray | None,
    title: str,
) -> Path:
    """Write a 3-D scatter plot; clouds are (N, 3) in metres."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scene = np.concatenate([hangers, cloth, *valid_goals])
    centre, half = scene.mean(axis=0), 0.5 * np.ptp(scene, axis=0).max() + 0.2
    low, high = centre - half, centre + half
    figure = plt.figure(figsize=(7, 6))
    axes = figure.add_subplot(projection="3d")
    axes.scatter(*hangers.T, s=2, c="0.4", label="hangers")
    axes.scatter(*cloth.T, s=2, c="tab:blue", label="cloth (start)")
    for i, goal in enumerate(valid_goals):
        axes.scatter(*goal.T, s=2, c="tab:green", alpha=0.45, label="valid goals" if i == 0 else None)
    if predicted_goal is not None:
        inside = np.all((predicted_goal >= low) & (predicted_goal <= high), axis=1)
        axes.scatter(*predicted_goal[inside].T, s=3, c="tab:red", label="predicted goal")
        if not inside.all():
            title += f" ({int((~inside).sum())} predicted points outside the view)"
    axes.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]), zlim=(max(0.0, low[2]), high[2]))
    axes.set(xlabel="x (m)", ylabel="y (m)", zlabel="z (m)")
    axes.set_title(title, fontsize=9)
    axes.legend(loc="upper left", fontsize=7, markerscale=4)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path
