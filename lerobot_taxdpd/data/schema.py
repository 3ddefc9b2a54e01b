"""The dataset schema every part of the project reads and writes (LeRobot v3.0, float32, metres, world frame).

Goal prediction (`taxdpd`): one demo = one episode of >= 2 frames (independent samplings or views of the
same demo: LeRobot 0.4.4 computes broken statistics for one-frame episodes).
- `observation.pointcloud.object` (N_O, 3): the segmented object at the start, P_O.
- `observation.pointcloud.scene`  (N_S, 3): the scene, P_S.
- `action` (N_O, 3): the goal cloud P*_O; row i is where row i of P_O must go.
- `goal.transform` (4, 4), rigid sources only: T* with P*_O = T* P_O. Not an `observation.*` key, so
  LeRobot's training loop never feeds it to a policy; evaluation tools read it.

Cloth policy (`gc_dp3`): one rollout = one episode; the clouds above plus `observation.pointcloud.goal`,
`observation.state`, a 6-d end-effector `action`, `next.done` and `next.success`.
"""

from __future__ import annotations

import numpy as np

from lerobot_taxdpd.data.validation import PointCloudError, check_point_cloud, check_rigid_transform, check_same_shape

OBJECT_KEY = "observation.pointcloud.object"
SCENE_KEY = "observation.pointcloud.scene"
GOAL_CLOUD_KEY = "observation.pointcloud.goal"
STATE_KEY = "observation.state"
ACTION_KEY = "action"
GOAL_TRANSFORM_KEY = "goal.transform"
DONE_KEY = "next.done"
SUCCESS_KEY = "next.success"
POINT_CLOUD_PREFIX = "observation.pointcloud."
#: Measured metrics saved beside a checkpoint's weights (and listed by `list_goal_predictors`).
METRICS_FILE = "metrics.json"

#: Frames per second written to goal-prediction datasets. Frames of one episode are views of one demo, not
#: a time series, so the value only matters to LeRobot's timestamp checks.
GOAL_DATASET_FPS = 10

#: The one deformable task: its goals are hung by a gc_dp3 executor rather than placed by a pose.
CLOTH_TASK = "cloth_hang"

#: (N_O, N_S) per task, from the paper's downsampling table; procedural tasks inherit their real analogue's.
DEFAULT_POINT_COUNTS: dict[str, tuple[int, int]] = {
    "mug_rack_easy_single": (512, 512),
    "mug_rack_med_single": (512, 512),
    "mug_rack_med_multi": (512, 1024),
    "book_on_bookshelf_double_view_rnd_ori": (512, 1024),
    "can_in_cabinet_stack": (256, 1024),
    "cloth_hang": (512, 512),
    "nist": (512, 1024),
}


def _cloud_feature(num_points: int) -> dict:
    return {"dtype": "float32", "shape": (num_points, 3), "names": None}


def goal_prediction_features(object_cloud_size: int, scene_cloud_size: int, *, with_transform: bool) -> dict:
    """LeRobot feature spec of a goal-prediction dataset."""
    features = {
        OBJECT_KEY: _cloud_feature(object_cloud_size),
        SCENE_KEY: _cloud_feature(scene_cloud_size),
        ACTION_KEY: _cloud_feature(object_cloud_size),
    }
    if with_transform:
        features[GOAL_TRANSFORM_KEY] = {"dtype": "float32", "shape": (4, 4), "names": None}
    return features


def cloth_policy_features(
    object_cloud_size: int, scene_cloud_size: int, *, state_dim: int = 12, action_dim: int = 6
) -> dict:
    """LeRobot feature spec of a goal-conditioned cloth-policy dataset (time series)."""
    return {
        OBJECT_KEY: _cloud_feature(object_cloud_size),
        SCENE_KEY: _cloud_feature(scene_cloud_size),
        GOAL_CLOUD_KEY: _cloud_feature(object_cloud_size),
        STATE_KEY: {"dtype": "float32", "shape": (state_dim,), "names": None},
        ACTION_KEY: {"dtype": "float32", "shape": (action_dim,), "names": None},
        DONE_KEY: {"dtype": "bool", "shape": (1,), "names": None},
        SUCCESS_KEY: {"dtype": "bool", "shape": (1,), "names": None},
    }


def placement_frame(
    object_points: np.ndarray,
    scene_points: np.ndarray,
    goal_points: np.ndarray,
    goal_transform: np.ndarray | None = None,
    *,
    source: str = "frame",
    transform_atol: float = 1e-3,
) -> dict[str, np.ndarray]:
    """Validate one goal-prediction sample and return it as a LeRobot frame (float32 arrays, no `task`).

    Checks finite (N, 3) clouds with at least 3 points, start/goal rows that correspond, a rigid T*, and
    that T* maps the start cloud onto the goal cloud (to `transform_atol` metres). Errors name `source`
    and the dataset field.
    """
    check_point_cloud(object_points, f"{source}: field '{OBJECT_KEY}'", min_points=3)
    check_point_cloud(scene_points, f"{source}: field '{SCENE_KEY}'", min_points=3)
    check_point_cloud(goal_points, f"{source}: field '{ACTION_KEY}'", min_points=3)
    check_same_shape(object_points, goal_points, f"{source}: field '{OBJECT_KEY}'", f"field '{ACTION_KEY}'")
    frame = {
        OBJECT_KEY: np.asarray(object_points, dtype=np.float32),
        SCENE_KEY: np.asarray(scene_points, dtype=np.float32),
        ACTION_KEY: np.asarray(goal_points, dtype=np.float32),
    }
    if goal_transform is not None:
        check_rigid_transform(goal_transform, f"{source}: field '{GOAL_TRANSFORM_KEY}'")
        t = np.asarray(goal_transform, dtype=np.float64)
        mapped = np.asarray(object_points, dtype=np.float64) @ t[:3, :3].T + t[:3, 3]
        error = float(np.abs(mapped - np.asarray(goal_points, dtype=np.float64)).max())
        if error > transform_atol:
            raise PointCloudError(
                f"{source}: field '{GOAL_TRANSFORM_KEY}' does not map '{OBJECT_KEY}' onto '{ACTION_KEY}' "
                f"(max error {error:.4g} m > {transform_atol:g} m)"
            )
        frame[GOAL_TRANSFORM_KEY] = t.astype(np.float32)
    return frame
