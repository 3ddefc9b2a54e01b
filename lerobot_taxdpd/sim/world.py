"""A private pybullet world per scene: DIRECT mode, fixed time step, a table plane at z = 0.

Every trial builds its scene in a fresh client and disconnects afterwards, so trials are independent
and the same seed always gives the same physics.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pybullet as pb

from lerobot_taxdpd.sim.bodies import box, create_body

TIME_STEP = 1.0 / 240.0
GRAVITY = 9.81
TABLE_HALF_SIZE = 1.5


@contextmanager
def physics_world() -> Iterator[int]:
    """Yield a fresh DIRECT pybullet client with gravity along -z; disconnect on exit."""
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=client)
        pb.setTimeStep(TIME_STEP, physicsClientId=client)
        yield client
    finally:
        pb.disconnect(client)


def add_table(client: int) -> int:
    """A static table whose top surface is the plane z = 0."""
    slab = box((TABLE_HALF_SIZE, TABLE_HALF_SIZE, 0.02), position=(0.0, 0.0, -0.02))
    return create_body(client, [slab], color=(0.55, 0.45, 0.35, 1.0), friction=0.8)


def simulate(client: int, seconds: float) -> None:
    for _ in range(int(round(seconds / TIME_STEP))):
        pb.stepSimulation(physicsClientId=client)
