"""Procedural mugs: a cylindrical cup (bottom disc and a ring of wall slabs) with a C-shaped handle.

The design frame has the mug's axis along +z and the handle on the +x side, in the x-z plane, so the
hole of the handle opens along y. The parts are shifted so the frame's origin is the centre of mass
(pybullet poses a dynamic body by its centre of mass). The design also solves where the mug rests when
it hangs from a horizontal-ish peg through its handle: the contact point on the inner edge of the handle
whose normal passes through the centre of mass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import Part, box, centre_of_mass, cylinder, shift_parts
from lerobot_taxdpd.sim.poses import quaternion, rot_y, rot_z
from lerobot_taxdpd.sim.splits import ParameterSpace

MUG_SPACE = ParameterSpace(
    name="mug",
    ranges={
        "radius": (0.030, 0.045),
        "height": (0.080, 0.115),
        "wall": (0.003, 0.005),
        "hole_height": (0.030, 0.050),
        "hole_width": (0.016, 0.028),
        "handle_thickness": (0.006, 0.009),
        "handle_width": (0.010, 0.016),
        "handle_centre": (0.45, 0.60),  # fraction of the height
    },
    keys=("radius", "hole_height"),
)

WALL_SEGMENTS = 20
HANDLE_SEGMENTS = 8
BOTTOM_THICKNESS = 0.005


@dataclass(frozen=True)
class MugDesign:
    params: dict[str, float]
    parts: tuple[Part, ...]
    bottom_z: float  # z of the bottom face in the (centre-of-mass) design frame
    hole_centre: np.ndarray  # centre of the handle's hole, design frame
    hang_contact: np.ndarray  # where the peg touches the handle when the mug hangs at rest
    hang_normal: np.ndarray  # unit normal there, pointing into the hole (towards the peg's centre)


def mug_design(params: dict[str, float]) -> MugDesign:
    """Build the parts of a mug from its parameters (metres)."""
    r, h, t = params["radius"], params["height"], params["wall"]
    hole_h, hole_w = params["hole_height"], params["hole_width"]
    b, w = params["handle_thickness"], params["handle_width"]
    z_c = float(np.clip(params["handle_centre"] * h, hole_h / 2 + b + 0.006, h - hole_h / 2 - b - 0.004))

    parts: list[Part] = [cylinder(r, BOTTOM_THICKNESS, position=(0.0, 0.0, BOTTOM_THICKNESS / 2))]
    half_chord = r * np.tan(np.pi / WALL_SEGMENTS) + 0.0005
    for i in range(WALL_SEGMENTS):
        angle = 2 * np.pi * i / WALL_SEGMENTS
        centre = ((r - t / 2) * np.cos(angle), (r - t / 2) * np.sin(angle), h / 2)
        parts.append(box((t / 2, half_chord, h / 2), centre, quaternion(rot_z(angle))))

    # Handle: boxes along a half-ellipse whose inner edge leaves a hole_w x hole_h opening.
    x0 = r - t / 2
    semi_x, semi_z = hole_w + t / 2 + b / 2, hole_h / 2 + b / 2
    phis = np.linspace(0.0, np.pi, HANDLE_SEGMENTS + 1)
    centreline = np.stack([x0 + semi_x * np.sin(phis), np.zeros_like(phis), z_c + semi_z * np.cos(phis)], -1)
    for a, c in zip(centreline[:-1], centreline[1:], strict=True):
        chord = c - a
        length = float(np.linalg.norm(chord)) + 0.6 * b
        pitch = -np.arctan2(chord[2], chord[0])
        parts.append(box((length / 2, w / 2, b / 2), (a + c) / 2, quaternion(rot_y(pitch))))

    com = centre_of_mass(parts)
    parts = shift_parts(parts, -com)
    inner_x, inner_z = semi_x - b / 2, semi_z - b / 2
    contact, normal = _hang_contact(np.array([x0, 0.0, z_c]) - com, inner_x, inner_z)
    hole_centre = np.array([r + hole_w / 2, 0.0, z_c]) - com
    return MugDesign(dict(params), tuple(parts), -float(com[2]), hole_centre, contact, normal)


def _hang_contact(centre: np.ndarray, semi_x: float, semi_z: float) -> tuple[np.ndarray, np.ndarray]:
    """Point of the handle's inner half-ellipse where the inward normal points at the origin (the COM).

    Hanging at rest, the peg's contact force is vertical and passes through the centre of mass, so the
    contact is where the inner edge's normal is aimed at the centre of mass.
    """
    phis = np.linspace(0.0, np.pi / 2, 400)
    points = centre + np.stack([semi_x * np.sin(phis), np.zeros_like(phis), semi_z * np.cos(phis)], -1)
    normals = -np.stack([np.sin(phis) / semi_x, np.zeros_like(phis), np.cos(phis) / semi_z], -1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    to_com = -points / np.linalg.norm(points, axis=-1, keepdims=True)
    best = int(np.argmax((normals * to_com).sum(-1)))
    return points[best], normals[best]
