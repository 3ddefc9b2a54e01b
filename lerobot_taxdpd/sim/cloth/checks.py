"""DEDO/TAX3D success for hanging a cloth by a hole.

Before release, a hole's centroid must lie within a radius of a hanger's goal point (the middle of its
peg). After release and settling, the peg must pass through that same hole: the hole's boundary loop,
projected onto the plane orthogonal to the peg, must wind around the peg's axis, and the loop must sit
between the pole and the tip. DEDO projects onto the ground plane because its hanger points up; the
projection along the peg is the same test for a peg of any direction.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lerobot_taxdpd.sim.cloth.scene import Hanger


def hole_centroids(vertices: np.ndarray, loops: Sequence[np.ndarray]) -> np.ndarray:
    """Centroid of each hole's boundary loop: (H, 3)."""
    return np.stack([vertices[loop].mean(axis=0) for loop in loops])


def winding_number(polygon: np.ndarray, point: np.ndarray) -> int:
    """Times the closed 2-D polygon (L, 2) winds around `point` (2,); 0 means outside."""
    rel = polygon - point
    angles = np.arctan2(rel[:, 1], rel[:, 0])
    turns = np.diff(np.append(angles, angles[0]))
    turns = (turns + np.pi) % (2 * np.pi) - np.pi
    return int(round(turns.sum() / (2 * np.pi)))


def loop_encircles_peg(loop_points: np.ndarray, hanger: Hanger) -> bool:
    """Whether the peg's axis threads the closed loop, with the loop between the pole and the tip."""
    axis = hanger.peg_direction
    u = np.cross(axis, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    rel = loop_points - hanger.peg_root
    along = rel @ axis
    if not 0.0 <= along.mean() <= hanger.shape.peg_length:
        return False
    return winding_number(np.stack([rel @ u, rel @ v], axis=1), np.zeros(2)) != 0


def pre_release_matrix(
    vertices: np.ndarray, loops: Sequence[np.ndarray], hangers: Sequence[Hanger], radius: float
) -> np.ndarray:
    """(holes, hangers) bool: hole centroid within `radius` of the hanger's goal point."""
    centroids = hole_centroids(vertices, loops)
    goals = np.stack([h.goal_point for h in hangers])
    return np.linalg.norm(centroids[:, None] - goals[None], axis=-1) < radius


def post_release_matrix(vertices: np.ndarray, loops: Sequence[np.ndarray], hangers: Sequence[Hanger]) -> np.ndarray:
    """(holes, hangers) bool: the hanger's peg threads the hole."""
    return np.array([[loop_encircles_peg(vertices[loop], h) for h in hangers] for loop in loops])
