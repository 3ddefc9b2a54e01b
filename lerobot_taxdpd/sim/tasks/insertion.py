"""Connector insertion with a millimetre of clearance, like the paper's NIST-board experiments.

A gripper holds the plug at a fixed capture pose, where two cameras below it see its bottom face and
lower sides; two cameras above the board see the sockets. The grasp varies as in the paper's data
(+-10 deg about the gripper's y axis, +-5 mm along x, 0 to +5 mm along z), so the plug's start pose and
the visible part of it change from trial to trial. The controller lowers the plug into the socket
along the socket's axis, kinematically, stopping at the first contact deeper than 0.1 mm.

Success: the plug is fully seated, its seat face within 1 mm of where it rests fully inserted and its
axis within the clearance of the socket's axis; released upside down, it slides out. `insert_waterproof_multi` has two
valid waterproof sockets and two distractors (a D-sub socket and an SSD slot) on the board.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import Part, box, create_body, place_parts
from lerobot_taxdpd.sim.cameras import CameraSpec, orbit_cameras
from lerobot_taxdpd.sim.designs.connectors import BUILDERS, CLEARANCE, SPACES, PlugDesign, SocketDesign
from lerobot_taxdpd.sim.poses import body_pose, quaternion, rot_y, rot_z, transform
from lerobot_taxdpd.sim.tasks.base import BuiltScene, GoalMode, PlacementTask
from lerobot_taxdpd.sim.world import add_table

PLUG_MASS = 0.02
BOARD_THICKNESS = 0.006
SEAT_GAP = 0.0002
SEAT_TOLERANCE = 0.001
CAPTURE_POSITION = np.array([0.22, 0.0, 0.20])
SOCKET_SPACING = 0.075
BOARD_MARGIN = 0.006


@dataclass(frozen=True)
class InsertionScene:
    plug: PlugDesign
    sockets: tuple[tuple[str, SocketDesign, np.ndarray], ...]  # (connector, design, mouth's pose on the board)
    valid: tuple[int, ...]  # indices of the sockets the plug fits
    board_pose: np.ndarray
    board_half: tuple[float, float]
    grasp: np.ndarray  # plug pose in the gripper frame
    gripper: np.ndarray  # world pose of the gripper when the plug is observed

    def socket_world(self, index: int) -> np.ndarray:
        return self.board_pose @ self.sockets[index][2]


class InsertionTask(PlacementTask):
    point_count_key = "nist"
    holds_object = True
    # The gripper holds the plug at one yaw in the robot's frame in every scene (only the grasp tilt varies),
    # and the plug's cloud does not show its yaw (its key is a few points within the depth noise). So the
    # robot's frame is the reference the goal's yaw is read in: no scene turn, no start yaw, and the board's
    # yaw (+-14 deg) is then visible against it. 22% -> 81% on held-out trials (docs/taxdpd.md, "The
    # connector reads its board").
    training_flags = ("--policy.start_yaw_range=0", "--policy.start_tilt_range=15", "--policy.z_rotation_range=0")
    approach_distance = 0.03
    coarse_step = 0.001
    fine_step = 0.00005
    penetration_tolerance = 0.0001
    depth_noise = 0.0003
    perturbation = (0.003, 3.0)
    coverage_threshold = 0.003

    def __init__(self, name: str, connector: str, multi: bool, description: str):
        self.name = name
        self.connector = connector
        self.multi = multi
        self.multi_modal = multi
        self.description = description

    # ------------------------------------------------------------------------------------------- scene
    def sample_scene(self, rng: np.random.Generator, split: str) -> InsertionScene:
        plug, socket = BUILDERS[self.connector](SPACES[self.connector].sample(rng, split))
        if self.multi:
            others = [(name, BUILDERS[name](SPACES[name].sample(rng, split))[1]) for name in ("dsub25", "ssd")]
            entries = [(self.connector, socket), (self.connector, socket), *others]
            order = rng.permutation(len(entries))
            grid = [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)]
            sockets = []
            for slot, index in enumerate(order):
                name, design = entries[index]
                x, y = np.asarray(grid[slot]) * SOCKET_SPACING + rng.uniform(-0.006, 0.006, size=2)
                sockets.append((name, design, transform(rot_z(rng.uniform(-0.3, 0.3)), (x, y, design.mouth_height))))
            valid = tuple(slot for slot, index in enumerate(order) if index < 2)
        else:
            sockets = [(self.connector, socket, transform(translation=(0.0, 0.0, socket.mouth_height)))]
            valid = (0,)
        # The board just covers the sockets, like the cropped scene clouds of the real experiments.
        half = tuple(
            max(abs(pose[axis, 3]) + design.half_extent for _, design, pose in sockets) + BOARD_MARGIN
            for axis in (0, 1)
        )
        board_pose = transform(
            rot_z(rng.uniform(-0.25, 0.25)), (rng.uniform(-0.015, 0.015), rng.uniform(-0.015, 0.015), BOARD_THICKNESS)
        )
        grasp = transform(
            rot_y(np.radians(rng.uniform(-10.0, 10.0))),
            (rng.uniform(-0.005, 0.005), 0.0, rng.uniform(0.0, 0.005)),
        ) @ transform(translation=-plug.top)
        gripper = transform(rot_z(np.pi / 2), CAPTURE_POSITION)
        return InsertionScene(plug, tuple(sockets), valid, board_pose, half, grasp, gripper)

    def board_parts(self, scene: InsertionScene) -> list[Part]:
        """The board (top face at z = 0 of its frame) with every socket on it."""
        hx, hy = scene.board_half
        parts = [box((hx, hy, BOARD_THICKNESS / 2), (0.0, 0.0, -BOARD_THICKNESS / 2))]
        for _, design, pose in scene.sockets:
            parts += place_parts(design.parts, pose)  # each socket's floor stands on the board
        return parts

    def build(self, client: int, scene: InsertionScene) -> BuiltScene:
        table = add_table(client)
        board = create_body(
            client,
            self.board_parts(scene),
            position=scene.board_pose[:3, 3],
            orientation=quaternion(scene.board_pose),
            color=(0.3, 0.3, 0.35, 1.0),
            friction=0.3,
        )
        start = self.start_pose(scene)
        plug = create_body(
            client,
            scene.plug.parts,
            mass=PLUG_MASS,
            position=start[:3, 3],
            orientation=quaternion(start),
            color=(0.9, 0.75, 0.2, 1.0),
            friction=0.3,
        )
        return BuiltScene(plug, (board,), table)

    def start_pose(self, scene: InsertionScene) -> np.ndarray:
        return scene.gripper @ scene.grasp

    def gripper_start_pose(self, scene: InsertionScene) -> np.ndarray:
        return scene.gripper

    def seat_pose(self, scene: InsertionScene, index: int) -> np.ndarray:
        """The plug's pose fully inserted into socket `index` (its seat face SEAT_GAP above where it stops)."""
        depth = scene.sockets[index][1].seat_depth
        return (
            scene.socket_world(index)
            @ transform(translation=(0.0, 0.0, -depth + SEAT_GAP))
            @ transform(translation=-scene.plug.seat)
        )

    # ------------------------------------------------------------------------------------------- goals
    def goal_modes(self, scene: InsertionScene) -> list[GoalMode]:
        return [GoalMode(f"socket {index}", (self.seat_pose(scene, index),)) for index in scene.valid]

    def object_cameras(self, scene: InsertionScene) -> list[CameraSpec]:
        target = self.start_pose(scene) @ np.append(scene.plug.seat, 1.0)
        return orbit_cameras(target[:3], 0.13, -45.0, (-20.0, 160.0), fov_deg=35.0, width=160, height=120, near=0.01)

    def scene_cameras(self, scene: InsertionScene) -> list[CameraSpec]:
        centre = scene.board_pose[:3, 3]
        distance = 0.32 if self.multi else 0.2
        return orbit_cameras(centre, distance, 60.0, (200.0, 340.0), fov_deg=40.0, width=256, height=192, near=0.01)

    # ---------------------------------------------------------------------------------------- execution
    def approach_direction(self, scene: InsertionScene, goal_pose: np.ndarray) -> np.ndarray:
        return -scene.board_pose[:3, 2]

    def check_result(self, client: int, built: BuiltScene, scene: InsertionScene) -> str | None:
        pose = body_pose(client, built.object_id)
        best = None
        for index in scene.valid:
            offset = np.linalg.inv(self.seat_pose(scene, index)) @ pose
            # How far the plug's seat face is from where it rests fully inserted, in the socket's frame.
            seat = offset[:3, :3] @ scene.plug.seat + offset[:3, 3] - scene.plug.seat
            lateral, height = float(np.linalg.norm(seat[:2])), float(seat[2])
            if best is None or lateral < best[0]:
                best = (lateral, height)
        lateral, height = best
        if lateral > CLEARANCE + 0.0001:
            return f"not in a socket ({lateral * 1000:.1f} mm off its axis)"
        if height > SEAT_TOLERANCE:
            return f"not fully seated ({height * 1000:.1f} mm high)"
        return None
