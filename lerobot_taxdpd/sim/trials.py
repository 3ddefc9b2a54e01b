"""The pipeline every task shares: scripted demonstrations, robot-like observations, execution.

`make_trial` samples a scene from a seed, keeps the goals the controller can actually reach (the
complete set of valid goals), lets the scripted demonstrator pick one, and renders the observation:
segmented, fused partial-view clouds from the task's depth cameras, downsampled by farthest point
sampling to the task's point counts, with the ground-truth goal cloud in row correspondence.
`execute` runs a predicted pose through the controller and the physical checks in a fresh world.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lerobot_taxdpd.maths.geometry import farthest_point_indices, transform_points
from lerobot_taxdpd.sim.cameras import jitter_cameras, render_segmented_clouds
from lerobot_taxdpd.sim.controller import penetration, sweep_to_goal
from lerobot_taxdpd.sim.poses import body_pose, set_body_pose
from lerobot_taxdpd.sim.splits import SPLITS, check_split
from lerobot_taxdpd.sim.success import upside_down_test
from lerobot_taxdpd.sim.tasks.base import BuiltScene, GoalMode, PlacementTask
from lerobot_taxdpd.sim.world import physics_world, simulate

MAX_SCENE_ATTEMPTS = 20
CAMERA_EYE_JITTER = 0.02  # metres, for extra views of the same demo
CAMERA_TARGET_JITTER = 0.01


@dataclass(frozen=True)
class Observation:
    """One view of a demo: the object and scene clouds (float32, metres, world frame)."""

    object_points: np.ndarray
    scene_points: np.ndarray


@dataclass(frozen=True)
class Trial:
    """A scene, its valid goals, the demonstrator's choice and one or more observations of it."""

    task: PlacementTask
    seed: int
    split: str
    scene: Any
    start_pose: np.ndarray
    goal_transform: np.ndarray  # T* of the demonstration: goal = T* @ start
    modes: tuple[GoalMode, ...]  # every reachable valid goal, grouped by mode
    views: tuple[Observation, ...]
    gripper_pose: np.ndarray | None  # insertion: the gripper holding the object when observed

    @property
    def object_points(self) -> np.ndarray:
        return self.views[0].object_points

    @property
    def scene_points(self) -> np.ndarray:
        return self.views[0].scene_points

    def goal_points(self, view: int = 0) -> np.ndarray:
        """The demonstration's goal cloud, row i = where point i of the object goes."""
        return transform_points(self.goal_transform, self.views[view].object_points).astype(np.float32)

    def valid_transforms(self) -> list[np.ndarray]:
        """Per mode, the (V, 4, 4) transforms T with goal = T @ start that solve the task."""
        inverse_start = np.linalg.inv(self.start_pose)
        return [np.stack([pose @ inverse_start for pose in mode.poses]) for mode in self.modes]


@dataclass(frozen=True)
class Outcome:
    """Result of executing one predicted pose."""

    success: bool
    reason: str  # empty on success
    reached_goal: bool  # the controller got all the way to the predicted pose
    final_pose: np.ndarray


def _rng(seed: int, split: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), SPLITS.index(check_split(split))])


def reachable_modes(task: PlacementTask, client: int, built: BuiltScene, scene: Any) -> list[GoalMode]:
    """The task's goal modes whose poses are collision-free and reachable by the controller."""
    start = task.start_pose(scene)
    modes = []
    for mode in task.goal_modes(scene):
        candidates = mode.poses[:1] if mode.symmetric else mode.poses
        poses = [pose for pose in candidates if _reachable(task, client, built, scene, pose)]
        if poses:
            modes.append(GoalMode(mode.label, mode.poses if mode.symmetric else tuple(poses), mode.symmetric))
    set_body_pose(client, built.object_id, start)
    return modes


def _reachable(task: PlacementTask, client: int, built: BuiltScene, scene: Any, pose: np.ndarray) -> bool:
    set_body_pose(client, built.object_id, pose)
    if penetration(client, built.object_id, built.obstacles) > 0.0:
        return False
    sweep = sweep_to_goal(
        client,
        built.object_id,
        pose,
        task.approach_direction(scene, pose),
        task.approach_distance,
        built.obstacles,
        coarse_step=task.coarse_step,
        fine_step=task.fine_step,
        tolerance=0.0,
    )
    return sweep.reached_goal


def _downsample(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray | None:
    if len(points) < count:
        return None
    indices = farthest_point_indices(points, count, start_index=int(rng.integers(len(points))))
    return points[indices].astype(np.float32)


def observe(
    task: PlacementTask, client: int, built: BuiltScene, scene: Any, rng: np.random.Generator, *, jitter: bool
) -> Observation | None:
    """Render the object and scene clouds; None when a camera setup sees too few points of either."""
    num_object, num_scene = task.num_points
    object_cameras, scene_cameras = task.object_cameras(scene), task.scene_cameras(scene)
    if jitter:
        object_cameras = jitter_cameras(object_cameras, rng, CAMERA_EYE_JITTER, CAMERA_TARGET_JITTER)
        scene_cameras = jitter_cameras(scene_cameras, rng, CAMERA_EYE_JITTER, CAMERA_TARGET_JITTER)
    noise = dict(depth_noise_std=task.depth_noise, rng=rng)
    object_points = render_segmented_clouds(client, object_cameras, [built.object_id], **noise)[built.object_id]
    scene_clouds = render_segmented_clouds(client, scene_cameras, built.parent_ids, **noise)
    scene_points = np.concatenate([scene_clouds[body] for body in built.parent_ids])
    object_points = _downsample(object_points, num_object, rng)
    scene_points = _downsample(scene_points, num_scene, rng)
    if object_points is None or scene_points is None:
        return None
    return Observation(object_points, scene_points)


def make_trial(task: PlacementTask, seed: int, split: str = "test", num_views: int = 1) -> Trial:
    """Sample a scene from `seed`, demonstrate it and observe it `num_views` times (view 0 is nominal).

    Deterministic in (task, seed, split). Scenes with no reachable goal, or that the cameras see too
    little of, are redrawn from the same random stream.
    """
    if num_views < 1:
        raise ValueError(f"num_views: must be at least 1, got {num_views}")
    rng = _rng(seed, split)
    for _ in range(MAX_SCENE_ATTEMPTS):
        scene = task.sample_scene(rng, split)
        with physics_world() as client:
            built = task.build(client, scene)
            modes = reachable_modes(task, client, built, scene)
            if not modes:
                continue
            views = [observe(task, client, built, scene, rng, jitter=i > 0) for i in range(num_views)]
        if any(view is None for view in views):
            continue
        start = task.start_pose(scene)
        mode = modes[int(rng.integers(len(modes)))]
        goal = task.demonstrated_pose(mode, scene)
        return Trial(
            task=task,
            seed=int(seed),
            split=split,
            scene=scene,
            start_pose=start,
            goal_transform=goal @ np.linalg.inv(start),
            modes=tuple(modes),
            views=tuple(views),
            gripper_pose=task.gripper_start_pose(scene),
        )
    raise RuntimeError(f"{task.name}: no feasible scene in {MAX_SCENE_ATTEMPTS} attempts for seed {seed} ({split})")


def execute(trial: Trial, transform: np.ndarray) -> Outcome:
    """Run the controller to the pose `transform @ start` in a fresh world and judge the result."""
    task, scene = trial.task, trial.scene
    transform = np.asarray(transform, dtype=np.float64)
    if transform.shape != (4, 4) or not np.isfinite(transform).all():
        raise ValueError(f"transform: expected a finite (4, 4) rigid transform, got shape {transform.shape}")
    goal_pose = transform @ trial.start_pose
    with physics_world() as client:
        built = task.build(client, scene)
        sweep = sweep_to_goal(
            client,
            built.object_id,
            goal_pose,
            task.approach_direction(scene, goal_pose),
            task.approach_distance,
            built.obstacles,
            coarse_step=task.coarse_step,
            fine_step=task.fine_step,
            tolerance=task.penetration_tolerance,
        )
        if not sweep.started:
            return Outcome(False, "pre-placement pose penetrates the scene", False, sweep.pose)
        if not task.holds_object:
            simulate(client, task.settle_seconds)
        final_pose = body_pose(client, built.object_id)
        reason = task.check_result(client, built, scene)
        if reason is None and not upside_down_test(client, built.object_id, built.parent_ids, built.table_id):
            reason = "stuck in the upside-down test (wedged into the scene)"
    return Outcome(reason is None, reason or "", sweep.reached_goal, final_pose)
