"""Mug/EasyRack, Mug/MedRack and Mug/Multi-MedRack: hang a mug by its handle on a rack's peg.

Valid goals: for every peg the controller can reach, the mug hanging at rest from that peg (handle
contact straight above the centre of mass, 2 mm above the peg), facing either way. The controller
slides the mug onto the peg nearest to the predicted handle position, along the peg's axis. Success:
after settling for a second the mug touches a peg (a contact point on a peg's surface) and not the
table, and it slides off when the rack is turned upside down.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import create_body
from lerobot_taxdpd.sim.cameras import CameraSpec, orbit_cameras
from lerobot_taxdpd.sim.designs.mugs import MUG_SPACE, MugDesign, mug_design
from lerobot_taxdpd.sim.designs.racks import RACK_SPACE, Peg, RackDesign, rack_design, sample_peg_layout
from lerobot_taxdpd.sim.poses import body_pose, quaternion, rot_z, transform
from lerobot_taxdpd.sim.success import contact_points, point_segment_distance, touching
from lerobot_taxdpd.sim.tasks.base import BuiltScene, GoalMode, PlacementTask
from lerobot_taxdpd.sim.world import add_table

MUG_MASS = 0.3
HANG_GAP = 0.002
RACK_SPACING = 0.34


@dataclass(frozen=True)
class MugScene:
    mug: MugDesign
    mug_start: np.ndarray
    racks: tuple[RackDesign, ...]
    rack_poses: tuple[np.ndarray, ...]
    hang_fraction: float  # where the handle hangs, as a fraction of a peg's reach

    def world_pegs(self) -> list[tuple[Peg, np.ndarray, np.ndarray]]:
        """(peg, world start, world tip) of every peg in the scene."""
        pegs = []
        for rack, pose in zip(self.racks, self.rack_poses, strict=True):
            for peg in rack.pegs:
                pegs.append((peg, pose[:3, :3] @ peg.start + pose[:3, 3], pose[:3, :3] @ peg.tip + pose[:3, 3]))
        return pegs


class MugRackTask(PlacementTask):
    point_count_key = "mug_rack_easy_single"
    symmetry_period_deg = 180.0  # hung facing either way
    perturbation = (0.02, 15.0)
    coverage_threshold = 0.02
    # The demos start the mug at every yaw already, and the goal has two valid facings: turning the object alone
    # (start-yaw augmentation) decouples the demonstrated facing from the start the network sees, so the same
    # view gets either facing as its target. Without it, held-out seeds 1000-1099: 39% -> 71%, rotation
    # 16.8 -> 6.2 deg (docs/taxdpd.md, "Symmetric goals and the start-yaw augmentation").
    training_flags = ("--policy.start_yaw_range=0",)

    def __init__(self, name: str, num_racks: int, pegs_per_rack: int, point_count_key: str, description: str):
        self.name = name
        self.num_racks = num_racks
        self.pegs_per_rack = pegs_per_rack
        self.multi_modal = num_racks * pegs_per_rack > 1
        self.point_count_key = point_count_key
        self.description = description

    # ------------------------------------------------------------------------------------------- scene
    def sample_scene(self, rng: np.random.Generator, split: str) -> MugScene:
        mug = mug_design(MUG_SPACE.sample(rng, split))
        racks, poses = [], []
        offset = (self.num_racks - 1) / 2
        for i in range(self.num_racks):
            params = RACK_SPACE.sample(rng, split)
            racks.append(rack_design(params, sample_peg_layout(rng, params, self.pegs_per_rack)))
            position = ((i - offset) * RACK_SPACING + rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), 0.0)
            poses.append(transform(rot_z(rng.uniform(0, 2 * np.pi)), position))
        angle = rng.uniform(-np.pi / 2 - 0.5, -np.pi / 2 + 0.5)
        distance = rng.uniform(0.30, 0.38)
        start_xy = np.array([np.cos(angle), np.sin(angle)]) * distance
        mug_start = transform(rot_z(rng.uniform(0, 2 * np.pi)), (*start_xy, -mug.bottom_z + 0.001))
        return MugScene(mug, mug_start, tuple(racks), tuple(poses), float(rng.uniform(0.55, 0.75)))

    def build(self, client: int, scene: MugScene) -> BuiltScene:
        table = add_table(client)
        racks = tuple(
            create_body(
                client,
                rack.parts,
                position=pose[:3, 3],
                orientation=quaternion(pose),
                color=(0.45, 0.3, 0.2, 1.0),
                friction=0.8,
            )
            for rack, pose in zip(scene.racks, scene.rack_poses, strict=True)
        )
        mug = create_body(
            client,
            scene.mug.parts,
            mass=MUG_MASS,
            position=scene.mug_start[:3, 3],
            orientation=quaternion(scene.mug_start),
            color=(0.85, 0.85, 0.9, 1.0),
            friction=0.8,
        )
        return BuiltScene(mug, racks, table)

    def start_pose(self, scene: MugScene) -> np.ndarray:
        return scene.mug_start

    # ------------------------------------------------------------------------------------------- goals
    def goal_modes(self, scene: MugScene) -> list[GoalMode]:
        modes = []
        for index, (peg, start, tip) in enumerate(scene.world_pegs()):
            direction = (tip - start) / np.linalg.norm(tip - start)
            along = np.linalg.norm(tip - start) - peg.reach * (1 - scene.hang_fraction)
            point = start + direction * along
            poses = tuple(self._hanging_pose(scene.mug, point, direction, peg.radius, side) for side in (1.0, -1.0))
            modes.append(GoalMode(f"peg {index}", poses))
        return modes

    @staticmethod
    def _hanging_pose(
        mug: MugDesign, point: np.ndarray, direction: np.ndarray, peg_radius: float, side: float
    ) -> np.ndarray:
        """Mug pose hanging at rest from the peg axis point `point`, its hole axis along `side * direction`."""
        up = np.array([0.0, 0.0, 1.0]) - direction[2] * direction
        up /= np.linalg.norm(up)
        y = np.array([0.0, 1.0, 0.0])
        n = mug.hang_normal
        design_axes = np.column_stack([n, y, np.cross(y, n)])
        hole_axis = side * direction
        world_axes = np.column_stack([-up, hole_axis, np.cross(hole_axis, -up)])
        rotation = world_axes @ design_axes.T
        contact = point + (peg_radius + HANG_GAP) * up
        return transform(rotation, contact - rotation @ mug.hang_contact)

    # -------------------------------------------------------------------------------------- observation
    def object_cameras(self, scene: MugScene) -> list[CameraSpec]:
        return orbit_cameras(scene.mug_start[:3, 3], 0.42, 35.0, (-40.0, 80.0), fov_deg=40.0, width=160, height=120)

    def scene_cameras(self, scene: MugScene) -> list[CameraSpec]:
        centre = np.mean([pose[:3, 3] for pose in scene.rack_poses], axis=0) + np.array([0.0, 0.0, 0.2])
        multi = self.num_racks > 1
        return orbit_cameras(
            centre,
            1.1 if multi else 0.7,
            25.0,
            (-120.0, -40.0, 60.0),
            fov_deg=45.0,
            width=320 if multi else 224,
            height=240 if multi else 168,
        )

    # ---------------------------------------------------------------------------------------- execution
    def approach_direction(self, scene: MugScene, goal_pose: np.ndarray) -> np.ndarray:
        """Slide along the peg nearest to the predicted handle, towards the pole."""
        hole = goal_pose[:3, :3] @ scene.mug.hole_centre + goal_pose[:3, 3]
        _, start, tip = min(scene.world_pegs(), key=lambda peg: point_segment_distance(hole, peg[1], peg[2]))
        return (start - tip) / np.linalg.norm(start - tip)

    def check_result(self, client: int, built: BuiltScene, scene: MugScene) -> str | None:
        if touching(client, built.object_id, [built.table_id]):
            return "fell to the table"
        for rack_id, rack, pose in zip(built.parent_ids, scene.racks, scene.rack_poses, strict=True):
            # The part of each peg outside the pole, in world coordinates.
            pegs = [
                (
                    pose[:3, :3] @ (peg.tip - peg.direction * peg.reach) + pose[:3, 3],
                    pose[:3, :3] @ peg.tip + pose[:3, 3],
                    peg.radius,
                )
                for peg in rack.pegs
            ]
            for point in contact_points(client, built.object_id, rack_id):
                on_rack = np.asarray(point[6])
                if any(point_segment_distance(on_rack, s, t) < r + 0.0015 for s, t, r in pegs):
                    return None
        height = body_pose(client, built.object_id)[2, 3]
        return f"not hanging on a peg (centre of mass at z = {height * 100:.1f} cm)"
