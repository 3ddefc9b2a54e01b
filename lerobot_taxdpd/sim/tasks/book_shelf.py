"""Book/Shelf: put a book lying on the table upright into one of the free slots of a bookshelf.

Valid goals: every free slot, the book standing upright 6 mm above the shelf board (it is let fall onto it),
centred in the slot and 4 mm in front of the back wall, in each of its four box symmetries. The controller pushes
the book in from the open front, perpendicular to the back wall. Success: after settling the book is
upright (within 15 deg), rests on the board between two neighbours of a free slot, does not touch the
table, and rises out of the open-topped shelf upside down (which also rejects any book wedged into it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import create_body
from lerobot_taxdpd.sim.cameras import CameraSpec, orbit_cameras
from lerobot_taxdpd.sim.designs.shelves import BACK_GAP, BOOK_SPACE, SHELF_SPACE, ShelfDesign, book_parts, shelf_design
from lerobot_taxdpd.sim.poses import body_pose, quaternion, rot_x, rot_y, rot_z, tilt_deg, transform
from lerobot_taxdpd.sim.success import touching
from lerobot_taxdpd.sim.tasks.base import BuiltScene, GoalMode, PlacementTask, least_turn_poses
from lerobot_taxdpd.sim.world import add_table

BOOK_MASS = 0.4
# How far above the board the book is let go. The controller pushes it in level from the front, so a book
# whose bottom is 1 mm or more below the board's top catches on its edge and falls (the ground truth lowered
# 3 mm: 0 of 40 placed), while one let go from 30 mm above still stands (40 of 40). At 1.5 mm the demonstrated
# goal sat 2 mm from that edge and a predictor's 2-3 mm height error fell off it; 6 mm leaves room both ways.
DROP_GAP = 0.006
BOX_SYMMETRIES = (np.eye(3), rot_z(np.pi), rot_x(np.pi), rot_y(np.pi))


@dataclass(frozen=True)
class BookScene:
    book: dict[str, float]
    book_start: np.ndarray
    shelf: ShelfDesign
    shelf_pose: np.ndarray


class BookShelfTask(PlacementTask):
    name = "book_shelf"
    description = "put the book upright into a free slot of the bookshelf"
    point_count_key = "book_on_bookshelf_double_view_rnd_ori"
    multi_modal = True
    symmetry_period_deg = 180.0  # turned around, it occupies the same space
    # As for the mugs: the demos start the book at every yaw, and its box symmetries make a turned start look
    # like another start, so a random start yaw makes the target one of four; without it the rotation error
    # halves and coverage@10 rises 0.03 -> 0.43 (success stays bounded by translation; docs/taxdpd.md).
    # The shelves face the robot within +-23 deg, so the scene turn of training spans +-30 deg, not the circle:
    # the local stage then finds the slot's depth and height from wherever its frame starts (first sample
    # 30% -> 60% on the choosing seeds; docs/taxdpd.md, "Where the local stage puts the book"). The shipped
    # recipe's pose-level terms are flags of the recipe, not of the task: they need the clean-sample point
    # diffusion, which the ablation variants replace.
    training_flags = ("--policy.start_yaw_range=0", "--policy.z_rotation_range=30")
    perturbation = (0.02, 15.0)
    coverage_threshold = 0.02
    approach_distance = 0.30

    def sample_scene(self, rng: np.random.Generator, split: str) -> BookScene:
        book = BOOK_SPACE.sample(rng, split)
        shelf = shelf_design(SHELF_SPACE.sample(rng, split), book, rng, num_slots=int(rng.integers(2, 4)))
        shelf_pose = transform(rot_z(rng.uniform(-0.4, 0.4)), (rng.uniform(-0.05, 0.05), rng.uniform(0.10, 0.18), 0.0))
        # The book lies on its side on the table, somewhere in front of the shelf.
        lying = rot_z(rng.uniform(0, 2 * np.pi)) @ rot_y(np.pi / 2 * rng.choice([-1.0, 1.0]))
        position = (rng.uniform(-0.2, 0.2), rng.uniform(-0.32, -0.22), book["thickness"] / 2 + 0.001)
        return BookScene(book, transform(lying, position), shelf, shelf_pose)

    def build(self, client: int, scene: BookScene) -> BuiltScene:
        table = add_table(client)
        shelf = create_body(
            client,
            scene.shelf.parts,
            position=scene.shelf_pose[:3, 3],
            orientation=quaternion(scene.shelf_pose),
            color=(0.6, 0.45, 0.3, 1.0),
            friction=0.5,
        )
        b = scene.book
        book = create_body(
            client,
            book_parts(b["thickness"], b["depth"], b["height"]),
            mass=BOOK_MASS,
            position=scene.book_start[:3, 3],
            orientation=quaternion(scene.book_start),
            color=(0.2, 0.4, 0.8, 1.0),
            friction=0.5,
        )
        return BuiltScene(book, (shelf,), table)

    def start_pose(self, scene: BookScene) -> np.ndarray:
        return scene.book_start

    def goal_modes(self, scene: BookScene) -> list[GoalMode]:
        b, shelf = scene.book, scene.shelf
        y = shelf.interior_y[1] - BACK_GAP - b["depth"] / 2
        z = shelf.floor_z + b["height"] / 2 + DROP_GAP
        modes = []
        for index, (low, high) in enumerate(shelf.slots):
            upright = transform(translation=((low + high) / 2, y, z))
            poses = tuple(scene.shelf_pose @ upright @ transform(symmetry) for symmetry in BOX_SYMMETRIES)
            modes.append(GoalMode(f"slot {index}", poses, symmetric=True))
        return modes

    def demonstrated_pose(self, mode: GoalMode, scene: BookScene) -> np.ndarray:
        """The least turn, and where two tie (they always do: upright facing one way, or on its head facing the
        other), the one that puts the side facing up at the start, the side the cameras see, on the shelf's +x
        side. Broken by rounding instead, half the demonstrations were the other pose, whose observed points'
        centroid lies about 17 mm further along the row (the unseen bottom face moves it off the box's centre)."""
        start = self.start_pose(scene)
        up_side = start[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the face that is up, in the book's own axes
        to_shelf = scene.shelf_pose[:3, :3].T
        return max(least_turn_poses(mode, start), key=lambda pose: (to_shelf @ pose[:3, :3] @ up_side)[0])

    def object_cameras(self, scene: BookScene) -> list[CameraSpec]:
        return orbit_cameras(scene.book_start[:3, 3], 0.5, 40.0, (-60.0, 60.0), fov_deg=45.0, width=160, height=120)

    def scene_cameras(self, scene: BookScene) -> list[CameraSpec]:
        centre = scene.shelf_pose @ np.array([0.0, 0.0, 0.12, 1.0])
        front = np.degrees(np.arctan2(-scene.shelf_pose[1, 1], -scene.shelf_pose[0, 1]))
        return orbit_cameras(centre[:3], 0.75, 35.0, (front - 35.0, front + 35.0), fov_deg=50.0, width=256, height=192)

    def approach_direction(self, scene: BookScene, goal_pose: np.ndarray) -> np.ndarray:
        return scene.shelf_pose[:3, 1].copy()

    def check_result(self, client: int, built: BuiltScene, scene: BookScene) -> str | None:
        if touching(client, built.object_id, [built.table_id]):
            return "fell to the table"
        pose = body_pose(client, built.object_id)
        upright = min(tilt_deg(pose, axis) for axis in ((0, 0, 1), (0, 0, -1)))
        if upright > 15.0:
            return f"not upright ({upright:.0f} deg)"
        local = np.linalg.inv(scene.shelf_pose) @ pose[:, 3]
        shelf = scene.shelf
        if not shelf.interior_y[0] <= local[1] <= shelf.interior_y[1]:
            return "not inside the shelf"
        if not any(low <= local[0] <= high for low, high in shelf.slots):
            return "not in a free slot"
        bottom = local[2] - scene.book["height"] / 2 * np.cos(np.radians(upright))
        if abs(bottom - shelf.floor_z) > 0.005:
            return f"not resting on the shelf board ({(bottom - shelf.floor_z) * 1000:.0f} mm above it)"
        return None
