"""Rigid bodies built from primitive parts: one builder for every procedural object and fixture.

A design is a list of `Part`s (boxes, cylinders, at most one convex prism) in the object's own frame.
Visual and collision geometry are the same parts, so what the depth cameras see is exactly what collides;
parts marked `collides=False` are drawn only (a connector's pins, whose mating holes are not modelled).

Three facts about Bullet (pybullet 3.2.7, measured) shape the builder:
- a shape array keeps only its first 16 children, silently: larger designs are split over fixed links;
- boxes and cylinders carry a 1 mm collision margin inside their extent, so their distances are exact
  only when every half extent is at least 1 mm (smaller colliding primitives are refused);
- a convex mesh is inflated by a 1 mm margin that can be removed only on a body's base, so the one
  prism a design may have (a connector's keyed cross-section) becomes the base with a zero margin.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import pybullet as pb

from lerobot_taxdpd.maths.geometry import matrix_to_quaternion_xyzw

IDENTITY_QUAT = (0.0, 0.0, 0.0, 1.0)
MAX_COMPOUND_CHILDREN = 16
MIN_COLLIDING_HALF_EXTENT = 0.001
ANCHOR_MASS_FRACTION = 0.01  # share of a dynamic body's mass on a shapeless base


@dataclass(frozen=True)
class Part:
    """One primitive of a design, posed in the design frame.

    `size`: box half extents (3); cylinder (radius, length along z); prism (z_low, z_high) of the convex
    polygon `outline` (counter-clockwise x, y vertices).
    """

    kind: str  # "box" | "cylinder" | "prism"
    size: tuple[float, ...] = ()
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = IDENTITY_QUAT
    outline: tuple[tuple[float, float], ...] = ()
    collides: bool = True

    def smallest_half_extent(self) -> float:
        if self.kind == "box":
            return min(self.size)
        if self.kind == "cylinder":
            return min(self.size[0], self.size[1] / 2)
        return float("inf")

    def volume(self) -> float:
        if self.kind == "box":
            return float(8.0 * np.prod(self.size))
        if self.kind == "cylinder":
            return float(np.pi * self.size[0] ** 2 * self.size[1])
        area, _ = _polygon_area_centroid(np.asarray(self.outline))
        return float(area * (self.size[1] - self.size[0]))

    def centroid(self) -> np.ndarray:
        """Centroid in the design frame."""
        local = np.zeros(3)
        if self.kind == "prism":
            _, xy = _polygon_area_centroid(np.asarray(self.outline))
            local = np.array([xy[0], xy[1], 0.5 * (self.size[0] + self.size[1])])
        rotation = np.asarray(pb.getMatrixFromQuaternion(self.orientation)).reshape(3, 3)
        return np.asarray(self.position) + rotation @ local

    def prism_vertices(self) -> np.ndarray:
        """(2M, 3) vertices of a prism: the outline at z_low, then at z_high."""
        xy = np.asarray(self.outline, dtype=np.float64)
        low = np.column_stack([xy, np.full(len(xy), self.size[0])])
        high = np.column_stack([xy, np.full(len(xy), self.size[1])])
        return np.vstack([low, high])


def box(
    half_extents: Sequence[float], position=(0.0, 0.0, 0.0), orientation=IDENTITY_QUAT, collides: bool = True
) -> Part:
    return Part("box", tuple(float(h) for h in half_extents), _vec(position), _quat(orientation), collides=collides)


def cylinder(
    radius: float, length: float, position=(0.0, 0.0, 0.0), orientation=IDENTITY_QUAT, collides: bool = True
) -> Part:
    return Part("cylinder", (float(radius), float(length)), _vec(position), _quat(orientation), collides=collides)


def prism(
    outline_xy: np.ndarray, z_low: float, z_high: float, position=(0.0, 0.0, 0.0), orientation=IDENTITY_QUAT
) -> Part:
    """A convex polygon (counter-clockwise) extruded from `z_low` to `z_high`."""
    xy = np.asarray(outline_xy, dtype=np.float64)
    area, _ = _polygon_area_centroid(xy)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 3 or area <= 0 or not z_high > z_low:
        raise ValueError("prism: need >= 3 counter-clockwise (x, y) vertices and z_high > z_low")
    outline = tuple((float(x), float(y)) for x, y in xy)
    return Part("prism", (float(z_low), float(z_high)), _vec(position), _quat(orientation), outline)


def _polygon_area_centroid(xy: np.ndarray) -> tuple[float, np.ndarray]:
    """Signed area (positive when counter-clockwise) and centroid of a polygon (shoelace formula)."""
    x, y = xy[:, 0], xy[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    if area == 0:
        return 0.0, xy.mean(0)
    cx = ((x + xn) * cross).sum() / (6 * area)
    cy = ((y + yn) * cross).sum() / (6 * area)
    return float(area), np.array([cx, cy])


def _vec(v) -> tuple[float, float, float]:
    return tuple(float(c) for c in v)  # type: ignore[return-value]


def _quat(q) -> tuple[float, float, float, float]:
    return tuple(float(c) for c in q)  # type: ignore[return-value]


def centre_of_mass(parts: Sequence[Part]) -> np.ndarray:
    """Volume-weighted centroid of a design (uniform density)."""
    volumes = np.array([p.volume() for p in parts])
    centroids = np.stack([p.centroid() for p in parts])
    return (volumes[:, None] * centroids).sum(0) / volumes.sum()


def shift_parts(parts: Sequence[Part], offset: np.ndarray) -> list[Part]:
    """Translate a design by `offset` (used to put a dynamic object's frame at its centre of mass)."""
    return [replace(p, position=_vec(np.asarray(p.position) + offset)) for p in parts]


def place_parts(parts: Sequence[Part], pose: np.ndarray) -> list[Part]:
    """Express a sub-design (e.g. a socket) in a parent design's frame, given its (4, 4) pose there."""
    rotation = pose[:3, :3]
    placed = []
    for p in parts:
        local = np.asarray(pb.getMatrixFromQuaternion(p.orientation)).reshape(3, 3)
        orientation = matrix_to_quaternion_xyzw(rotation @ local)
        placed.append(
            replace(p, position=_vec(rotation @ np.asarray(p.position) + pose[:3, 3]), orientation=_quat(orientation))
        )
    return placed


def _prism_triangles(m: int) -> list[int]:
    """Outward-facing triangles of a prism whose M outline vertices run counter-clockwise."""
    indices: list[int] = []
    for i in range(1, m - 1):
        indices += [0, i + 1, i]  # bottom, facing -z
        indices += [m, m + i, m + i + 1]  # top, facing +z
    for i in range(m):
        j = (i + 1) % m
        indices += [i, j, m + j, i, m + j, m + i]
    return indices


def _prism_shapes(client: int, part: Part) -> tuple[int, int]:
    verts = part.prism_vertices().tolist()
    collision = pb.createCollisionShape(
        pb.GEOM_MESH,
        vertices=verts,
        collisionFramePosition=list(part.position),
        collisionFrameOrientation=list(part.orientation),
        physicsClientId=client,
    )
    visual = pb.createVisualShape(
        pb.GEOM_MESH,
        vertices=verts,
        indices=_prism_triangles(len(part.outline)),
        visualFramePosition=list(part.position),
        visualFrameOrientation=list(part.orientation),
        physicsClientId=client,
    )
    return collision, visual


def _compound_shapes(client: int, group: Sequence[Part]) -> tuple[int, int]:
    """Collision (-1 for drawn-only parts) and visual shape of up to 16 boxes and cylinders."""
    kinds = [pb.GEOM_BOX if p.kind == "box" else pb.GEOM_CYLINDER for p in group]
    shape = dict(
        halfExtents=[list(p.size) if p.kind == "box" else [0.0, 0.0, 0.0] for p in group],
        radii=[p.size[0] if p.kind == "cylinder" else 0.0 for p in group],
        lengths=[p.size[1] if p.kind == "cylinder" else 0.0 for p in group],
        physicsClientId=client,
    )
    positions = [list(p.position) for p in group]
    orientations = [list(p.orientation) for p in group]
    visual = pb.createVisualShapeArray(
        kinds, visualFramePositions=positions, visualFrameOrientations=orientations, **shape
    )
    if not group[0].collides:
        return -1, visual
    collision = pb.createCollisionShapeArray(
        kinds, collisionFramePositions=positions, collisionFrameOrientations=orientations, **shape
    )
    return collision, visual


def _check_parts(parts: Sequence[Part]) -> None:
    if not parts:
        raise ValueError("a body needs at least one part")
    if sum(p.kind == "prism" for p in parts) > 1:
        raise ValueError("a body may have at most one prism part (it becomes the body's base)")
    for p in parts:
        if p.collides and p.smallest_half_extent() < MIN_COLLIDING_HALF_EXTENT:
            raise ValueError(
                f"{p.kind} part of size {p.size} is thinner than 2 mm: Bullet's 1 mm collision margin would "
                "inflate it; make it larger or mark it collides=False"
            )


def create_body(
    client: int,
    parts: Sequence[Part],
    *,
    mass: float = 0.0,
    position=(0.0, 0.0, 0.0),
    orientation=IDENTITY_QUAT,
    color=(0.7, 0.7, 0.7, 1.0),
    friction: float = 0.6,
) -> int:
    """Create one pybullet body from `parts`; `mass` 0 makes it static. Returns the body id.

    The base sits at the design frame's origin (the prism if there is one, else shapeless); the other
    parts are fixed links, compounds of at most 16 primitives, each with its share of the mass at its
    own centroid.
    """
    _check_parts(parts)
    total_volume = sum(p.volume() for p in parts)
    prisms = [p for p in parts if p.kind == "prism"]
    if prisms:
        base_collision, base_visual = _prism_shapes(client, prisms[0])
        base_mass = mass * prisms[0].volume() / total_volume
    else:
        base_collision, base_visual, base_mass = -1, -1, ANCHOR_MASS_FRACTION * mass
    groups: list[list[Part]] = []
    for collides in (True, False):
        primitives = [p for p in parts if p.kind != "prism" and p.collides == collides]
        groups += [primitives[i : i + MAX_COMPOUND_CHILDREN] for i in range(0, len(primitives), MAX_COMPOUND_CHILDREN)]
    link_mass = mass - base_mass
    primitive_volume = sum(p.volume() for group in groups for p in group)
    shapes = [_compound_shapes(client, group) for group in groups]
    n = len(groups)
    body = pb.createMultiBody(
        baseMass=base_mass,
        baseCollisionShapeIndex=base_collision,
        baseVisualShapeIndex=base_visual,
        basePosition=list(_vec(position)),
        baseOrientation=list(_quat(orientation)),
        linkMasses=[link_mass * sum(p.volume() for p in group) / primitive_volume for group in groups],
        linkCollisionShapeIndices=[collision for collision, _ in shapes],
        linkVisualShapeIndices=[visual for _, visual in shapes],
        linkPositions=[[0.0, 0.0, 0.0]] * n,
        linkOrientations=[list(IDENTITY_QUAT)] * n,
        linkInertialFramePositions=[centre_of_mass(group).tolist() for group in groups],
        linkInertialFrameOrientations=[list(IDENTITY_QUAT)] * n,
        linkParentIndices=[0] * n,
        linkJointTypes=[pb.JOINT_FIXED] * n,
        linkJointAxis=[[0.0, 0.0, 1.0]] * n,
        physicsClientId=client,
    )
    for link in range(-1 if prisms else 0, n):
        pb.changeVisualShape(body, link, rgbaColor=list(color), physicsClientId=client)
        pb.changeDynamics(body, link, lateralFriction=friction, physicsClientId=client)
    if prisms:
        pb.changeDynamics(body, -1, collisionMargin=0.0, physicsClientId=client)
    return body
