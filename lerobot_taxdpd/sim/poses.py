"""4x4 homogeneous poses for pybullet bodies, and the small rotations the tasks are built from.

Everything in the benchmark is a numpy float64 (4, 4) matrix in the world frame; conversion to
pybullet's (position, xyzw quaternion) pairs happens only here.
"""

from __future__ import annotations

import numpy as np
import pybullet as pb
import torch

from lerobot_taxdpd.maths.geometry import (
    axis_angle_to_matrix,
    matrix_to_quaternion_xyzw,
    pose_to_matrix,
    rotation_angle,
)


def body_pose(client: int, body: int) -> np.ndarray:
    position, quaternion = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    return pose_to_matrix(np.asarray(position), np.asarray(quaternion))


def set_body_pose(client: int, body: int, pose: np.ndarray) -> None:
    """Teleport a body (zero velocity), as the placement controller does."""
    quaternion = matrix_to_quaternion_xyzw(np.asarray(pose[:3, :3], dtype=np.float64))
    pb.resetBasePositionAndOrientation(body, pose[:3, 3].tolist(), quaternion.tolist(), physicsClientId=client)
    pb.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=client)


def quaternion(pose_or_rotation: np.ndarray) -> list[float]:
    """xyzw quaternion of a (4, 4) pose or (3, 3) rotation, as pybullet wants it."""
    return matrix_to_quaternion_xyzw(np.asarray(pose_or_rotation, dtype=np.float64)[:3, :3]).tolist()


def axis_rotation(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by `angle` radians about `axis`."""
    k = torch.as_tensor(np.asarray(axis, dtype=np.float64))
    return axis_angle_to_matrix(k / k.norm(), torch.tensor(float(angle), dtype=torch.float64)).numpy()


def rot_x(angle: float) -> np.ndarray:
    return axis_rotation((1.0, 0.0, 0.0), angle)


def rot_y(angle: float) -> np.ndarray:
    return axis_rotation((0.0, 1.0, 0.0), angle)


def rot_z(angle: float) -> np.ndarray:
    return axis_rotation((0.0, 0.0, 1.0), angle)


def transform(rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) pose from a (3, 3) rotation (default identity) and a translation."""
    pose = np.eye(4)
    if rotation is not None:
        pose[:3, :3] = rotation
    pose[:3, 3] = translation
    return pose


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Geodesic angle of a (3, 3) rotation, in degrees."""
    return float(np.degrees(rotation_angle(torch.as_tensor(np.asarray(rotation, dtype=np.float64)[:3, :3]))))


def random_unit_vector(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def perturbation(rng: np.random.Generator, translation: float, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """A rigid error of exactly `translation` metres (uniform direction) and `angle_deg` (uniform axis)."""
    rotation = axis_rotation(random_unit_vector(rng), np.radians(angle_deg))
    return rotation, translation * random_unit_vector(rng)


def tilt_deg(pose: np.ndarray, local_axis=(0.0, 0.0, 1.0)) -> float:
    """Angle between a body's `local_axis` (in world) and world +z."""
    axis = pose[:3, :3] @ np.asarray(local_axis, dtype=np.float64)
    return float(np.degrees(np.arccos(np.clip(axis[2] / np.linalg.norm(axis), -1.0, 1.0))))
