"""The procedural placement tasks as gymnasium envs, in the form `lerobot-eval` drives them.

LeRobot 0.4.4's evaluation loop forwards only `environment_state`, `agent_pos` and `pixels` from an
env's observation, so both clouds travel in `environment_state`: the N_O object rows, then the N_S
scene rows (float32, metres, world frame); the taxdpd preprocessor splits them again. The action is the
goal cloud, (N_O, 3) or flattened to N_O * 3 values (lerobot-eval requires (batch, action_dim) actions).
The env fits a pose to it with RANSAC-SVD, runs the placement controller and the physical checks: reward 1
and `info["is_success"]` True on success.

An episode has two steps: the first action is executed; the second step ignores its action and ends the
episode with the same verdict. lerobot-eval's videos keep the frames up to the step that ends an episode
(and its vector env resets a finished env before rendering it), so this second step is what lets the
video show the placed object after the start scene.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from lerobot_taxdpd.maths.geometry import estimate_rigid_transform
from lerobot_taxdpd.sim.cameras import CameraSpec, orbit_cameras, render_rgb
from lerobot_taxdpd.sim.poses import set_body_pose
from lerobot_taxdpd.sim.splits import check_split
from lerobot_taxdpd.sim.tasks import get_task
from lerobot_taxdpd.sim.trials import Outcome, Trial, execute, make_trial
from lerobot_taxdpd.sim.world import physics_world

RENDER_SIZE = (320, 240)
VIDEO_ELEVATION_DEG = 35.0
VIDEO_FOV_DEG = 45.0


class PlacementEnv(gym.Env):
    """A held-out scene per reset, one placement per episode (then one step that shows it; see above)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 1}

    def __init__(
        self, task: str, split: str = "test", render_mode: str | None = "rgb_array", scene_cloud_size: int | None = None
    ):
        self._task = get_task(task).with_scene_cloud_size(scene_cloud_size)
        self.split = check_split(split)
        self.render_mode = render_mode
        self.task = task
        self.task_description = self._task.description
        num_object, num_scene = self._task.num_points
        self.observation_space = spaces.Dict(
            {"environment_state": spaces.Box(-np.inf, np.inf, (num_object + num_scene, 3), np.float32)}
        )
        self.action_space = spaces.Box(-np.inf, np.inf, (num_object, 3), np.float32)
        self._trial: Trial | None = None
        self._outcome: Outcome | None = None

    def _observation(self) -> dict[str, np.ndarray]:
        packed = np.concatenate([self._trial.object_points, self._trial.scene_points]).astype(np.float32)
        return {"environment_state": packed}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        scene_seed = int(seed) if seed is not None else int(self.np_random.integers(2**31 - 1))
        self._trial = make_trial(self._task, scene_seed, self.split)
        self._outcome = None
        return self._observation(), {"scene_seed": scene_seed}

    def step(self, action: np.ndarray):
        if self._trial is None:
            raise RuntimeError("call reset() before step()")
        if self._outcome is not None:  # the placement is done: end the episode on its verdict
            return self._observation(), 0.0, True, False, self._info()
        object_points = self._trial.object_points.astype(np.float64)
        goal = np.asarray(action, dtype=np.float64)
        if goal.size != object_points.size:
            raise ValueError(
                f"action: expected the goal cloud, {object_points.shape} or {object_points.size} values, "
                f"got shape {goal.shape}"
            )
        goal = goal.reshape(object_points.shape)
        if not np.isfinite(goal).all():
            raise ValueError("action: the goal cloud contains NaN or infinite values")
        transform, _ = estimate_rigid_transform(object_points, goal)
        self._outcome = execute(self._trial, transform)
        return self._observation(), float(self._outcome.success), False, False, self._info()

    def _info(self) -> dict[str, Any]:
        return {"is_success": self._outcome.success, "failure": self._outcome.reason}

    def render(self) -> np.ndarray:
        """The scene and the object (where the last placement left it) from a camera framing both."""
        if self._trial is None:
            raise RuntimeError("call reset() before render()")
        camera = _video_camera(self._trial, self._task.scene_cameras(self._trial.scene)[0])
        with physics_world() as client:
            built = self._task.build(client, self._trial.scene)
            if self._outcome is not None:
                set_body_pose(client, built.object_id, self._outcome.final_pose)
            return render_rgb(client, camera)


def _video_camera(trial: Trial, scene_camera: CameraSpec) -> CameraSpec:
    """A camera on the side of the first scene camera that frames the object's start and the whole scene:
    the task cameras look at one or the other, and a video must show where the object went from where."""
    points = np.concatenate([trial.object_points, trial.scene_points]).astype(np.float64)
    centre = (points.max(0) + points.min(0)) / 2
    radius = np.linalg.norm(points - centre, axis=1).max()
    side = np.subtract(scene_camera.eye, scene_camera.target)
    azimuth = float(np.degrees(np.arctan2(side[1], side[0])))
    distance = 1.15 * radius / np.sin(np.radians(VIDEO_FOV_DEG / 2))
    (camera,) = orbit_cameras(
        centre, distance, VIDEO_ELEVATION_DEG, [azimuth], fov_deg=VIDEO_FOV_DEG, width=RENDER_SIZE[0],
        height=RENDER_SIZE[1], far=distance + 2 * radius + 1.0,
    )
    return camera
