"""What a `cloth_hang` episode is made of: the cloth, its holes, its start pose and two hangers.

Sizes follow DEDO's HangProcCloth, whose scene is large (pybullet units are metres; DEDO scales its hangers
by 10 and its cloth by 3), so goal errors read on the same scale as the paper's coverage and precision RMSE.
A hanger is a pole on a base disc with one peg that sticks out of it, tilted up so a hanging cloth slides
towards the pole rather than off the tip; all three are cylinders. The cloth must be hung by one of its
holes on the peg of one of the hangers.

Splits: the test split holds out a third of all hole shapes (position and size on the grid), so every
test cloth has holes the training data never contains, and its layouts come from an independent random
stream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lerobot_taxdpd.maths.geometry import farthest_point_indices
from lerobot_taxdpd.sim.cloth.mesh import Hole, sample_holes

SPLITS = ("train", "test")


@dataclass(frozen=True)
class HangerShape:
    """Cylinder sizes shared by every hanger (metres)."""

    base_radius: float = 0.5
    base_height: float = 0.1
    pole_radius: float = 0.1
    peg_radius: float = 0.08
    peg_length: float = 1.2  # from the pole axis to the tip
    peg_tilt_deg: float = 15.0  # upwards
    pole_above_peg: float = 0.8  # the pole goes on above the peg, so a cloth sliding back cannot pass over it


@dataclass(frozen=True)
class Hanger:
    """A hanger standing at (x, y) on the ground; its peg points along yaw (0 = +y) at `peg_height`."""

    x: float
    y: float
    yaw: float
    peg_height: float
    shape: HangerShape = field(default_factory=HangerShape)

    @property
    def heading(self) -> np.ndarray:
        """Horizontal unit vector from the pole towards the peg tip."""
        return np.array([-math.sin(self.yaw), math.cos(self.yaw), 0.0])

    @property
    def peg_direction(self) -> np.ndarray:
        tilt = math.radians(self.shape.peg_tilt_deg)
        return math.cos(tilt) * self.heading + np.array([0.0, 0.0, math.sin(tilt)])

    @property
    def pole_height(self) -> float:
        return self.peg_height + self.shape.pole_above_peg

    @property
    def peg_root(self) -> np.ndarray:
        return np.array([self.x, self.y, self.peg_height])

    @property
    def peg_tip(self) -> np.ndarray:
        return self.peg_root + self.shape.peg_length * self.peg_direction

    @property
    def goal_point(self) -> np.ndarray:
        """Middle of the exposed part of the peg: where a hole's centroid should be before release."""
        s = self.shape
        return self.peg_root + 0.5 * (s.pole_radius + s.peg_length) * self.peg_direction

    @property
    def pose(self) -> np.ndarray:
        """4x4 world pose (yaw about z, origin at the foot of the pole)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s, 0, self.x], [s, c, 0, self.y], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)


@dataclass(frozen=True)
class SceneRanges:
    """Ranges the scene sampler draws from (metres, radians)."""

    node_density: int = 15
    num_holes: tuple[int, ...] = (1, 2)
    cloth_width: tuple[float, float] = (2.0, 2.8)
    cloth_height: tuple[float, float] = (2.0, 2.8)
    cloth_x: tuple[float, float] = (-0.8, 0.8)
    cloth_y: tuple[float, float] = (0.8, 1.6)
    cloth_top_z: tuple[float, float] = (6.4, 6.8)
    cloth_yaw: tuple[float, float] = (-math.pi / 6, math.pi / 6)
    hanger_x: tuple[float, float] = (-3.2, 3.2)
    hanger_y: tuple[float, float] = (-3.2, -2.6)
    hanger_yaw: tuple[float, float] = (-math.pi / 6, math.pi / 6)
    peg_height: tuple[float, float] = (4.4, 5.0)
    min_hanger_distance: float = 4.0


@dataclass(frozen=True)
class ClothScene:
    """Everything random about one episode; the simulation is a deterministic function of it."""

    split: str
    seed: int
    node_density: int
    cloth_width: float
    cloth_height: float
    holes: tuple[Hole, ...]
    cloth_center: tuple[float, float, float]  # midpoint of the two grippers at the start
    cloth_yaw: float  # 0: gripper 0 at -x, gripper 1 at +x, cloth facing +y
    hangers: tuple[Hanger, ...]


def is_test_hole(hole: Hole) -> bool:
    """The held-out third of hole shapes (position and size on the grid)."""
    return (hole.x0 + 2 * hole.y0 + (hole.x1 - hole.x0) + 2 * (hole.y1 - hole.y0)) % 3 == 0


def sample_scene(split: str, seed: int, ranges: SceneRanges | None = None) -> ClothScene:
    """Draw the scene of episode `seed` of `split`; the same (split, seed) always gives the same scene."""
    if split not in SPLITS:
        raise ValueError(f"split: must be one of {SPLITS}, got {split!r}")
    if seed < 0:
        raise ValueError(f"seed: must be non-negative, got {seed}")
    r = ranges or SceneRanges()
    rng = np.random.default_rng([SPLITS.index(split), seed])
    want_test = split == "test"
    num_holes = int(rng.choice(r.num_holes))
    holes = sample_holes(rng, r.node_density, num_holes, accept=lambda h: is_test_hole(h) == want_test)
    cloth_center = (float(rng.uniform(*r.cloth_x)), float(rng.uniform(*r.cloth_y)), float(rng.uniform(*r.cloth_top_z)))
    return ClothScene(
        split=split,
        seed=seed,
        node_density=r.node_density,
        cloth_width=float(rng.uniform(*r.cloth_width)),
        cloth_height=float(rng.uniform(*r.cloth_height)),
        holes=tuple(holes),
        cloth_center=cloth_center,
        cloth_yaw=float(rng.uniform(*r.cloth_yaw)),
        hangers=_sample_hangers(rng, r),
    )


def _sample_hangers(rng: np.random.Generator, r: SceneRanges, count: int = 2) -> tuple[Hanger, ...]:
    for _ in range(1000):
        xy = np.stack([rng.uniform(*r.hanger_x, size=count), rng.uniform(*r.hanger_y, size=count)], axis=1)
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1)[np.triu_indices(count, 1)]
        if gaps.min() >= r.min_hanger_distance:
            break
    else:
        raise RuntimeError("hanger_x/hanger_y ranges too small for min_hanger_distance")
    order = np.argsort(xy[:, 0])  # hanger 0 is the left one, so indices mean the same in every scene
    return tuple(
        Hanger(
            x=float(xy[i, 0]),
            y=float(xy[i, 1]),
            yaw=float(rng.uniform(*r.hanger_yaw)),
            peg_height=float(rng.uniform(*r.peg_height)),
        )
        for i in order
    )


def hanger_surface_points(hangers: tuple[Hanger, ...], num_points: int, rng: np.random.Generator) -> np.ndarray:
    """Points on the hangers' cylinder surfaces (base side and top, pole, peg and its tip cap), FPS-thinned."""
    parts = []
    for hanger in hangers:
        s = hanger.shape
        up = np.array([0.0, 0.0, 1.0])
        foot = np.array([hanger.x, hanger.y, 0.0])
        pole_height = hanger.pole_height
        parts.append(_cylinder_side(foot, up, s.base_radius, s.base_height))
        parts.append(_disc(foot + s.base_height * up, up, s.base_radius))
        parts.append(_cylinder_side(foot, up, s.pole_radius, pole_height))
        parts.append(_disc(foot + pole_height * up, up, s.pole_radius))
        parts.append(_cylinder_side(hanger.peg_root, hanger.peg_direction, s.peg_radius, s.peg_length))
        parts.append(_disc(hanger.peg_tip, hanger.peg_direction, s.peg_radius))
    areas = np.array([area for _, area in parts])
    counts = rng.multinomial(num_points * 8, areas / areas.sum())
    points = np.concatenate([sample(rng, k) for (sample, _), k in zip(parts, counts, strict=True) if k])
    return points[farthest_point_indices(points, num_points)]


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to `axis` and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def _cylinder_side(start: np.ndarray, axis: np.ndarray, radius: float, length: float):
    u, v = _frame(axis)

    def sample(rng: np.random.Generator, k: int) -> np.ndarray:
        angle = rng.uniform(0, 2 * np.pi, k)[:, None]
        along = rng.uniform(0, length, k)[:, None]
        return start + along * axis + radius * (np.cos(angle) * u + np.sin(angle) * v)

    return sample, 2 * np.pi * radius * length


def _disc(center: np.ndarray, normal: np.ndarray, radius: float):
    u, v = _frame(normal)

    def sample(rng: np.random.Generator, k: int) -> np.ndarray:
        angle = rng.uniform(0, 2 * np.pi, k)[:, None]
        rho = radius * np.sqrt(rng.random(k))[:, None]
        return center + rho * (np.cos(angle) * u + np.sin(angle) * v)

    return sample, np.pi * radius**2
