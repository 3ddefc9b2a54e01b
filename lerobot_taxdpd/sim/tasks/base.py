"""What every placement task defines, and the constants the pipeline reads from it.

A task samples scenes (pure data, reproducible from a seed and a split), builds them in a pybullet
world, lists every valid goal, says where its cameras are, which way the controller approaches a
goal, and how to judge the settled (or held) result. The shared pipeline in `trials.py` does the rest:
demonstrations, observations, execution and the upside-down test.
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from lerobot_taxdpd.data.schema import DEFAULT_POINT_COUNTS
from lerobot_taxdpd.sim.cameras import CameraSpec
from lerobot_taxdpd.sim.poses import rotation_angle_deg


@dataclass(frozen=True)
class GoalMode:
    """One way to solve a scene (a peg, a slot, a support, a socket) and its equally valid object poses.

    `poses` are world poses of the object; several when the object is symmetric or can be mirrored there
    (a box-shaped book turned around, a mug hung facing either way). `symmetric` says the poses occupy
    exactly the same space (symmetries of the object), so reaching one of them means reaching all.
    """

    label: str
    poses: tuple[np.ndarray, ...]
    symmetric: bool = False


@dataclass(frozen=True)
class BuiltScene:
    """Body ids of a scene built in one pybullet client."""

    object_id: int
    parent_ids: tuple[int, ...]  # what the scene cloud shows: racks, shelf and books, sockets, ...
    table_id: int

    @property
    def obstacles(self) -> tuple[int, ...]:
        return (*self.parent_ids, self.table_id)


class PlacementTask(ABC):
    """Base class of the procedural benchmarks; subclasses set the class attributes below."""

    name: str
    description: str  # the plain-language task string written to datasets
    point_count_key: str  # key of DEFAULT_POINT_COUNTS (the paper's point counts of the analogous task)
    multi_modal: bool = False  # scenes can have several valid goals: report coverage@K and precision@K
    # A turn about the vertical that maps the object's valid placements onto each other (a mug hung facing
    # either way, a box turned around): the equivariance probe folds yaw by it. None: no such turn.
    symmetry_period_deg: float | None = None
    # lerobot-train flags this task's predictors train with on top of the recipe (a user's flags come after
    # them and win): what the task's start poses make sensible, e.g. how far to turn the object at random.
    training_flags: tuple[str, ...] = ()
    holds_object: bool = False  # insertion: the gripper keeps the plug; rigid tasks release and settle
    approach_distance: float = 0.15
    coarse_step: float = 0.005
    fine_step: float = 0.0005
    penetration_tolerance: float = 0.001
    settle_seconds: float = 1.0
    depth_noise: float = 0.001  # std of simulated depth noise, metres
    perturbation: tuple[float, float] = (0.02, 15.0)  # tolerance-scale error (metres, degrees)
    coverage_threshold: float = 0.02  # RMSE (metres) under which a sample counts as reaching a goal
    scene_cloud_size: int | None = None  # scene points observed and recorded; None: the paper's count

    @property
    def num_points(self) -> tuple[int, int]:
        """(N_O, N_S) of observations and datasets."""
        num_object, num_scene = DEFAULT_POINT_COUNTS[self.point_count_key]
        return num_object, self.scene_cloud_size or num_scene

    def with_scene_cloud_size(self, size: int | None) -> PlacementTask:
        """This task observing `size` scene points (None: the paper's count): a denser recording, from which
        a local stage crops the scene around its frame (`local_scene_points`) at a finer spacing."""
        if size is None or size == self.num_points[1]:
            return self
        if size < 16:
            raise ValueError(f"scene cloud size: at least 16 points, got {size}")
        dense = copy.copy(self)
        dense.scene_cloud_size = size
        return dense

    @abstractmethod
    def sample_scene(self, rng: np.random.Generator, split: str) -> Any:
        """Geometry and poses of one scene; pure data, so the scene can be rebuilt anywhere."""

    @abstractmethod
    def build(self, client: int, scene: Any) -> BuiltScene:
        """Create the table, the scene bodies and the object (at its start pose) in `client`."""

    @abstractmethod
    def start_pose(self, scene: Any) -> np.ndarray:
        """World pose of the object when it is observed."""

    @abstractmethod
    def goal_modes(self, scene: Any) -> list[GoalMode]:
        """Every candidate valid goal; the pipeline drops the ones the controller cannot reach."""

    def demonstrated_pose(self, mode: GoalMode, scene: Any) -> np.ndarray:
        """Which of a mode's equally valid poses the demonstrator puts the object in: the least turn from the
        start. A task whose least turns tie overrides this, since a choice the observations cannot tell apart
        makes the demonstrated target a coin flip the model cannot learn."""
        return least_turn_poses(mode, self.start_pose(scene))[0]

    @abstractmethod
    def object_cameras(self, scene: Any) -> list[CameraSpec]:
        """Cameras that see the object at its start pose (two or more, partial views)."""

    @abstractmethod
    def scene_cameras(self, scene: Any) -> list[CameraSpec]:
        """Cameras that see the scene (two or more)."""

    @abstractmethod
    def approach_direction(self, scene: Any, goal_pose: np.ndarray) -> np.ndarray:
        """Unit world vector along which the controller moves the object into `goal_pose`."""

    @abstractmethod
    def check_result(self, client: int, built: BuiltScene, scene: Any) -> str | None:
        """Judge the object after it settled (or, for held objects, where the controller left it).

        Returns None on success, else a short reason ("fell to the table", "not seated: 2.1 mm high").
        """

    def gripper_start_pose(self, scene: Any) -> np.ndarray | None:
        """World pose of the gripper holding the object when it is observed (insertion tasks only)."""
        return None


def least_turn_poses(mode: GoalMode, start_pose: np.ndarray, tie_deg: float = 0.5) -> list[np.ndarray]:
    """The poses of `mode` within `tie_deg` of the least turn from `start_pose`, least turn first."""
    turns = [rotation_angle_deg(pose[:3, :3] @ start_pose[:3, :3].T) for pose in mode.poses]
    order = sorted(range(len(turns)), key=turns.__getitem__)
    return [mode.poses[i] for i in order if turns[i] <= turns[order[0]] + tie_deg]
