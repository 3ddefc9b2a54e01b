"""Simulated depth cameras: segmented, fused, world-frame point clouds as a robot would see them.

Each camera renders depth and a segmentation mask with pybullet's TinyRenderer (works headless), the
depth pixels are lifted to world coordinates, and the points of every requested body are collected
across cameras. Views are partial and occluded exactly as the scene is; nothing here knows about
tasks, so the rigid benchmarks and the cloth task share it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pybullet as pb


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole depth camera looking from `eye` at `target` (metres, world frame)."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 45.0
    width: int = 160
    height: int = 120
    near: float = 0.02
    far: float = 3.0

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera width/height must be positive, got {self.width}x{self.height}")
        if not 0 < self.near < self.far:
            raise ValueError(f"camera clipping planes must satisfy 0 < near < far, got {self.near}, {self.far}")
        direction = np.subtract(self.target, self.eye)
        if np.linalg.norm(direction) < 1e-9:
            raise ValueError("camera eye and target coincide")
        if np.linalg.norm(np.cross(direction, self.up)) < 1e-6 * np.linalg.norm(direction) * np.linalg.norm(self.up):
            raise ValueError(f"camera up vector {self.up} is parallel to the viewing direction; choose another")


def orbit_cameras(
    target: Sequence[float],
    distance: float,
    elevation_deg: float,
    azimuths_deg: Iterable[float],
    **spec,
) -> list[CameraSpec]:
    """Cameras on a circle around `target`, all looking at it (negative elevation looks up from below)."""
    target = np.asarray(target, dtype=np.float64)
    cameras = []
    for azimuth in azimuths_deg:
        a, e = np.radians(azimuth), np.radians(elevation_deg)
        offset = distance * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        cameras.append(CameraSpec(eye=tuple(target + offset), target=tuple(target), **spec))
    return cameras


def jitter_cameras(
    cameras: Sequence[CameraSpec], rng: np.random.Generator, eye_std: float, target_std: float
) -> list[CameraSpec]:
    """Independent small moves of each camera: another view of the same scene for data augmentation."""
    return [
        replace(
            camera,
            eye=tuple(np.asarray(camera.eye) + rng.normal(scale=eye_std, size=3)),
            target=tuple(np.asarray(camera.target) + rng.normal(scale=target_std, size=3)),
        )
        for camera in cameras
    ]


def _camera_matrices(camera: CameraSpec) -> tuple[np.ndarray, np.ndarray]:
    """View and projection matrices of a camera, as pybullet's column-major lists."""
    view = pb.computeViewMatrix(camera.eye, camera.target, camera.up)
    projection = pb.computeProjectionMatrixFOV(camera.fov_deg, camera.width / camera.height, camera.near, camera.far)
    return np.asarray(view), np.asarray(projection)


def render_depth(client: int, camera: CameraSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render one camera: world points (H, W, 3), segmentation (H, W) body ids (-1 background), RGB."""
    view, projection = _camera_matrices(camera)
    _, _, rgb, depth, segmentation = pb.getCameraImage(
        camera.width,
        camera.height,
        viewMatrix=view.tolist(),
        projectionMatrix=projection.tolist(),
        renderer=pb.ER_TINY_RENDERER,
        physicsClientId=client,
    )
    depth = np.asarray(depth, dtype=np.float64).reshape(camera.height, camera.width)
    segmentation = np.asarray(segmentation).reshape(camera.height, camera.width)
    rgb = np.asarray(rgb, dtype=np.uint8).reshape(camera.height, camera.width, 4)[..., :3]
    # pybullet matrices are column-major: reshape(4, 4).T gives the usual row-major matrix.
    clip_from_world = projection.reshape(4, 4).T @ view.reshape(4, 4).T
    world_from_clip = np.linalg.inv(clip_from_world)
    # TinyRenderer samples pixel (i, j) at NDC (2i/W - 1, 1 - 2(j+1)/H): measured, exact on flat targets.
    u = np.arange(camera.width) / camera.width * 2.0 - 1.0
    v = 1.0 - (np.arange(camera.height) + 1.0) / camera.height * 2.0
    ndc_x, ndc_y = np.meshgrid(u, v)
    ndc = np.stack([ndc_x, ndc_y, 2.0 * depth - 1.0, np.ones_like(depth)], -1)
    world = ndc @ world_from_clip.T
    points = world[..., :3] / world[..., 3:4]
    return points, segmentation, rgb


def render_segmented_clouds(
    client: int,
    cameras: Sequence[CameraSpec],
    body_ids: Iterable[int],
    *,
    depth_noise_std: float = 0.0,
    rng: np.random.Generator | None = None,
) -> dict[int, np.ndarray]:
    """Fuse the cameras' depth into one world-frame (N_b, 3) cloud per requested body.

    `depth_noise_std` (metres) moves each point along its camera ray, like a depth sensor's noise.
    Bodies no camera sees get an empty (0, 3) array; callers decide whether that is an error.
    """
    if not cameras:
        raise ValueError("render_segmented_clouds: at least one camera is needed")
    if depth_noise_std > 0 and rng is None:
        raise ValueError("render_segmented_clouds: depth noise needs an `rng`")
    wanted = list(body_ids)
    parts: dict[int, list[np.ndarray]] = {body: [] for body in wanted}
    for camera in cameras:
        points, segmentation, _ = render_depth(client, camera)
        for body in wanted:
            mask = segmentation == body
            if not mask.any():
                continue
            selected = points[mask]
            if depth_noise_std > 0:
                rays = selected - np.asarray(camera.eye)
                rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
                selected = selected + rays * rng.normal(scale=depth_noise_std, size=(len(selected), 1))
            parts[body].append(selected)
    return {body: np.concatenate(chunks) if chunks else np.zeros((0, 3)) for body, chunks in parts.items()}


def render_rgb(client: int, camera: CameraSpec) -> np.ndarray:
    """An RGB image (H, W, 3) uint8 of the scene, for videos and figures."""
    return render_depth(client, camera)[2]
