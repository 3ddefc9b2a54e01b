"""Can/Cabinet: put a can standing on the table on top of a stack of cans, or on the cabinet's open shelf.

Valid goals: the top of every single-can stack (a second can still fits under the shelf above) and every
free spot of the upper shelf, the can upright 3 mm above its support, at any turn about its axis
(listed every 15 deg, plus the turn it starts with). The controller slides the can in from the open front
at the goal's height. Success: after settling the can is upright within 15 deg, its base sits on a
valid support (on a stack's top can within one radius of the stack's axis, or on the upper shelf board
inside the cabinet), it does not touch the table, and it falls off when the cabinet is turned over.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import create_body
from lerobot_taxdpd.sim.cameras import CameraSpec, orbit_cameras
from lerobot_taxdpd.sim.designs.cabinets import CABINET_SPACE, CAN_SPACE, CabinetDesign, cabinet_design, can_parts
from lerobot_taxdpd.sim.poses import body_pose, quaternion, rot_z, tilt_deg, transform
from lerobot_taxdpd.sim.success import touching
from lerobot_taxdpd.sim.tasks.base import BuiltScene, GoalMode, PlacementTask
from lerobot_taxdpd.sim.world import add_table

CAN_MASS = 0.35
DROP_GAP = 0.003
YAW_STEP_DEG = 15.0


@dataclass(frozen=True)
class CanScene:
    can: dict[str, float]
    can_start: np.ndarray
    cabinet: CabinetDesign
    cabinet_pose: np.ndarray


class CanCabinetTask(PlacementTask):
    name = "can_cabinet"
    description = "put the can on top of a stack of cans or on the open shelf of the cabinet"
    point_count_key = "can_in_cabinet_stack"
    multi_modal = True
    perturbation = (0.05, 25.0)  # a can radius plus the gap to its neighbours: cans tolerate more than mugs
    coverage_threshold = 0.025
    approach_distance = 0.35

    def sample_scene(self, rng: np.random.Generator, split: str) -> CanScene:
        can = CAN_SPACE.sample(rng, split)
        cabinet = cabinet_design(CABINET_SPACE.sample(rng, split), can, rng)
        cabinet_pose = transform(rot_z(rng.uniform(-0.4, 0.4)), (rng.uniform(-0.05, 0.05), rng.uniform(0.12, 0.2), 0.0))
        start = transform(
            rot_z(rng.uniform(0, 2 * np.pi)),
            (rng.uniform(-0.2, 0.2), rng.uniform(-0.3, -0.2), can["height"] / 2 + 0.001),
        )
        return CanScene(can, start, cabinet, cabinet_pose)

    def build(self, client: int, scene: CanScene) -> BuiltScene:
        table = add_table(client)
        cabinet = create_body(
            client,
            scene.cabinet.parts,
            position=scene.cabinet_pose[:3, 3],
            orientation=quaternion(scene.cabinet_pose),
            color=(0.5, 0.5, 0.55, 1.0),
            friction=0.6,
        )
        can = create_body(
            client,
            can_parts(scene.can["radius"], scene.can["height"]),
            mass=CAN_MASS,
            position=scene.can_start[:3, 3],
            orientation=quaternion(scene.can_start),
            color=(0.8, 0.2, 0.2, 1.0),
            friction=0.6,
        )
        return BuiltScene(can, (cabinet,), table)

    def start_pose(self, scene: CanScene) -> np.ndarray:
        return scene.can_start

    def goal_modes(self, scene: CanScene) -> list[GoalMode]:
        start_yaw = np.arctan2(scene.can_start[1, 0], scene.can_start[0, 0])
        yaws = [start_yaw, *np.radians(np.arange(0.0, 360.0, YAW_STEP_DEG))]
        modes = []
        for support in scene.cabinet.supports:
            centre = support.centre + np.array([0.0, 0.0, scene.can["height"] / 2 + DROP_GAP])
            # The cabinet's own turn is undone so the listed yaws are world yaws.
            poses = tuple(
                scene.cabinet_pose @ transform(scene.cabinet_pose[:3, :3].T @ rot_z(yaw), centre) for yaw in yaws
            )
            modes.append(GoalMode(support.label, poses, symmetric=True))
        return modes

    def object_cameras(self, scene: CanScene) -> list[CameraSpec]:
        return orbit_cameras(scene.can_start[:3, 3], 0.45, 35.0, (-60.0, 60.0), fov_deg=40.0, width=160, height=120)

    def scene_cameras(self, scene: CanScene) -> list[CameraSpec]:
        centre = scene.cabinet_pose @ np.array([0.0, 0.0, 0.2, 1.0])
        front = np.degrees(np.arctan2(-scene.cabinet_pose[1, 1], -scene.cabinet_pose[0, 1]))
        return orbit_cameras(centre[:3], 0.8, 20.0, (front - 30.0, front + 30.0), fov_deg=50.0, width=256, height=192)

    def approach_direction(self, scene: CanScene, goal_pose: np.ndarray) -> np.ndarray:
        return scene.cabinet_pose[:3, 1].copy()

    def check_result(self, client: int, built: BuiltScene, scene: CanScene) -> str | None:
        if touching(client, built.object_id, [built.table_id]):
            return "fell to the table"
        pose = body_pose(client, built.object_id)
        tilt = tilt_deg(pose)
        if tilt > 15.0:
            return f"not upright ({tilt:.0f} deg)"
        base = np.linalg.inv(scene.cabinet_pose) @ (pose @ np.array([0.0, 0.0, -scene.can["height"] / 2, 1.0]))
        cabinet, radius = scene.cabinet, scene.can["radius"]
        if not touching(client, built.object_id, built.parent_ids):
            return "touches no support"
        for support in cabinet.supports:
            if abs(base[2] - support.centre[2]) > 0.006:
                continue
            if support.stack is not None and np.linalg.norm(base[:2] - support.centre[:2]) < radius:
                return None
            inside = (
                cabinet.interior_x[0] <= base[0] <= cabinet.interior_x[1]
                and cabinet.interior_y[0] <= base[1] <= cabinet.interior_y[1]
            )
            if support.stack is None and inside:
                return None
        return "not on a stack's top or the open shelf"
