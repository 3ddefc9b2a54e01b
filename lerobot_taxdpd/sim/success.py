"""Physical success checks shared by the rigid tasks, in the spirit of RPDiff's simulator.

A placement counts only if the simulated object ends up where the task wants it (each task checks its
own conditions: handle on a peg, book in a slot, can upright on a support, plug seated) *and* survives
the upside-down test: with gravity reversed (equivalent to flipping the scene) and the table removed,
an object that merely rests on or hangs from its parent falls away (it leaves the parent, or at least
moves until something else stops it, like a can inside a cabinet), while one that is wedged into it
(an interpenetrating placement) stays where it is. Bullet resolves deep penetrations by pushing bodies
apart, so a wedged object can slip out once flipped (measured: a block 3 mm into each of two walls
does); the test therefore also rejects an object that starts it more than `WEDGE_TOLERANCE` inside its
parent.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pybullet as pb

from lerobot_taxdpd.sim.controller import penetration
from lerobot_taxdpd.sim.world import GRAVITY, simulate

UPSIDE_DOWN_SECONDS = 2.0
#: Friction during the upside-down test. Low enough that a mug slides off an inverted peg tilted 15 deg or
#: more; a wedged object is held by contact forces, not by friction, so it stays stuck anyway.
UPSIDE_DOWN_FRICTION = 0.05
#: How far an object must move during the upside-down test if it still touches its parent afterwards.
UPSIDE_DOWN_MIN_TRAVEL = 0.005
#: Deeper than resting contacts ever settle (< 1 mm), shallower than any real interpenetration.
WEDGE_TOLERANCE = 0.002


def contact_points(client: int, body: int, other: int, distance: float = 0.001) -> list[tuple]:
    """Closest-point records between two bodies that are within `distance` (touching or penetrating)."""
    return list(pb.getClosestPoints(body, other, distance, physicsClientId=client))


def touching(client: int, body: int, others: Sequence[int], distance: float = 0.001) -> bool:
    return any(contact_points(client, body, other, distance) for other in others)


def upside_down_test(
    client: int, body: int, parents: Sequence[int], table: int, seconds: float = UPSIDE_DOWN_SECONDS
) -> bool:
    """True if `body` falls away from its parents once gravity is reversed (the table taken away)."""
    if penetration(client, body, parents) > WEDGE_TOLERANCE:
        return False
    before = np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
    for link in range(-1, pb.getNumJoints(body, physicsClientId=client)):
        pb.setCollisionFilterPair(body, table, link, -1, 0, physicsClientId=client)
        pb.changeDynamics(body, link, lateralFriction=UPSIDE_DOWN_FRICTION, physicsClientId=client)
    for parent in parents:
        for link in range(-1, pb.getNumJoints(parent, physicsClientId=client)):
            pb.changeDynamics(parent, link, lateralFriction=UPSIDE_DOWN_FRICTION, physicsClientId=client)
    pb.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=client)
    pb.setGravity(0.0, 0.0, GRAVITY, physicsClientId=client)
    try:
        simulate(client, seconds)
    finally:
        pb.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=client)
    after = np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
    moved = float(np.linalg.norm(after - before))
    return moved > UPSIDE_DOWN_MIN_TRAVEL or not touching(client, body, parents, distance=0.002)


def point_segment_distance(point: np.ndarray, start: np.ndarray, end: np.ndarray) -> float:
    """Distance from a point to the segment [start, end] (e.g. a contact point to a peg's axis)."""
    axis = end - start
    t = np.clip(np.dot(point - start, axis) / np.dot(axis, axis), 0.0, 1.0)
    return float(np.linalg.norm(point - (start + t * axis)))
