"""The placement controller: teleport to a pre-placement pose, then move straight to the goal.

As in RPDiff's insertion controller, the object is teleported to a pose offset from the predicted goal
against the approach direction and then moved along that direction. The motion is kinematic, in small
steps, and stops at the last pose that does not penetrate an obstacle by more than the task's tolerance:
a goal that cannot be reached without passing through the scene ends where the object got stuck, as a
position-controlled robot would. Coarse steps find the first collision, fine steps locate it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from lerobot_taxdpd.sim.poses import set_body_pose


@dataclass(frozen=True)
class SweepResult:
    """Where the controller left the object and how far it got."""

    pose: np.ndarray
    reached_goal: bool
    remaining: float  # metres between the final pose and the goal along the approach
    started: bool = True  # False when the pre-placement pose itself penetrates the scene


def penetration(client: int, body: int, obstacles: Sequence[int], probe: float = 0.005) -> float:
    """Deepest penetration (metres, >= 0) between `body` and any obstacle at their current poses."""
    deepest = 0.0
    for obstacle in obstacles:
        for point in pb.getClosestPoints(body, obstacle, probe, physicsClientId=client):
            deepest = max(deepest, -point[8])
    return deepest


def sweep_to_goal(
    client: int,
    body: int,
    goal_pose: np.ndarray,
    direction: np.ndarray,
    distance: float,
    obstacles: Sequence[int],
    *,
    coarse_step: float,
    fine_step: float,
    tolerance: float,
) -> SweepResult:
    """Move `body` from `goal_pose - distance * direction` to `goal_pose` until it would collide.

    If even the pre-placement pose penetrates the scene (a goal deep inside an obstacle), the controller
    cannot start: the result says so and the object is left at its pre-placement pose.
    """
    direction = np.asarray(direction, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)

    def pose_at(travel: float) -> np.ndarray:
        pose = np.array(goal_pose, dtype=np.float64)
        pose[:3, 3] += direction * (travel - distance)
        return pose

    def free(travel: float) -> bool:
        set_body_pose(client, body, pose_at(travel))
        return penetration(client, body, obstacles) <= tolerance

    if not free(0.0):
        set_body_pose(client, body, pose_at(0.0))
        return SweepResult(pose_at(0.0), False, distance, started=False)
    last_free = 0.0
    for step in (coarse_step, fine_step):
        travel = last_free
        while travel < distance:
            candidate = min(travel + step, distance)
            if not free(candidate):
                break
            travel = last_free = candidate
        if last_free >= distance:
            break
    final = pose_at(last_free)
    set_body_pose(client, body, final)
    return SweepResult(final, last_free >= distance, distance - last_free)
