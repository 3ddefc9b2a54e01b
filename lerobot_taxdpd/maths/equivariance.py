"""Does a goal predictor read orientation off the scene, or copy it from the object's start pose?

A correct predictor's goal follows the scene (turn the scene about the vertical and the goal turns with it)
and ignores how the object happens to be held (turn or tilt the object alone and the goal stays). A
predictor that copies the start orientation does the opposite. Each probe samples K goals with one seed
for the scene as observed and for a perturbed copy, fits the rigid motion between corresponding samples
(row correspondence) and reads how far the goal turned.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from lerobot_taxdpd.maths.geometry import axis_angle_to_matrix, fit_rigid_transform, rotation_about_z

#: Held-out scenes (the first ones evaluated) the shipped predictors' probe runs on.
PROBE_SCENES = 8

#: Names of the figures `goal_turn_response` reports, with the answer of a correct predictor.
IDEAL = {"scene_yaw": "the angle", "object_yaw": 0.0, "object_tilt": 0.0}


def _turned(points: Tensor, rotation: Tensor, pivot: Tensor) -> Tensor:
    return (points - pivot) @ rotation.transpose(-1, -2) + pivot


def _fold(yaw_deg: np.ndarray, period_deg: float | None) -> np.ndarray:
    """Yaw modulo the object's symmetry period, mapped to (-period/2, period/2]."""
    if period_deg is None:
        return yaw_deg
    return -((-yaw_deg + period_deg / 2) % period_deg - period_deg / 2)


def goal_turn_response(
    predictor,
    object_points: Tensor,
    scene_points: Tensor,
    *,
    angle_deg: float = 20.0,
    tilt_deg: float = 10.0,
    num_samples: int = 4,
    seed: int = 0,
    symmetry_period_deg: float | None = None,
) -> dict[str, float]:
    """Median turn of the predicted goal (degrees) when the scene alone, or the object alone, is turned.

    object_points (B, N_O, 3), scene_points (B, N_S, 3), metres, z up. Returns
    - scene_yaw: goal yaw change when the scene turns by `angle_deg` about the vertical through its centroid
      (correct: `angle_deg`; copying the start pose: 0);
    - object_yaw: goal yaw change when the object alone turns by `angle_deg` about its own vertical
      (correct: 0; copying: `angle_deg`);
    - object_tilt: goal turn about the horizontal x axis when the object alone tilts by `tilt_deg` about it,
      through its centroid, as a grasp holds a plug tilted (correct: 0; copying: `tilt_deg`).
    `symmetry_period_deg` folds yaw for objects that look the same turned by that angle (180 for a box).
    """
    object_points = torch.as_tensor(object_points, dtype=torch.float32)
    scene_points = torch.as_tensor(scene_points, dtype=torch.float32)
    turn = rotation_about_z(torch.tensor(math.radians(angle_deg)))
    tilt = axis_angle_to_matrix(torch.tensor([1.0, 0.0, 0.0]), torch.tensor(math.radians(tilt_deg)))
    object_pivot = object_points.mean(1, keepdim=True)
    cases = {
        "scene_yaw": (object_points, _turned(scene_points, turn, scene_points.mean(1, keepdim=True))),
        "object_yaw": (_turned(object_points, turn, object_pivot), scene_points),
        "object_tilt": (_turned(object_points, tilt, object_pivot), scene_points),
    }

    def sample(obj: Tensor, scene: Tensor) -> np.ndarray:
        generator = torch.Generator().manual_seed(seed)
        goals = predictor.sample_goals(obj, scene, num_samples, generator=generator)
        return torch.as_tensor(goals).detach().cpu().double().numpy()

    reference = sample(object_points, scene_points)
    response = {}
    for name, (obj, scene) in cases.items():
        motion = fit_rigid_transform(reference, sample(obj, scene))[..., :3, :3]
        if name == "object_tilt":  # signed turn about the tilt's axis (x), so sampling noise averages out
            values = np.degrees(np.arctan2(motion[..., 2, 1], motion[..., 2, 2]))
        else:
            values = _fold(np.degrees(np.arctan2(motion[..., 1, 0], motion[..., 0, 0])), symmetry_period_deg)
        response[name] = float(np.median(values))
    return response


def equivariance_report(
    predictor,
    object_points,
    scene_points,
    *,
    angle_deg: float = 20.0,
    tilt_deg: float = 10.0,
    symmetry_period_deg: float | None = None,
) -> dict:
    """`goal_turn_response` (4 samples a scene) with the probe's settings and ideal answers beside it: the
    `equivariance_deg` entry of a shipped predictor's metrics, which its model card renders."""
    turns = goal_turn_response(
        predictor,
        object_points,
        scene_points,
        angle_deg=angle_deg,
        tilt_deg=tilt_deg,
        num_samples=4,
        symmetry_period_deg=symmetry_period_deg,
    )
    return {
        "angle": angle_deg,
        "tilt_angle": tilt_deg,
        "trials": len(object_points),
        **turns,
        "ideal": {"scene_yaw": angle_deg, "object_yaw": 0.0, "object_tilt": 0.0},
    }
