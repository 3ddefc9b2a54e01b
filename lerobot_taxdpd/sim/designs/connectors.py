"""Procedural connectors and sockets in the spirit of the NIST assembly task board.

Three shapes: a round "waterproof" plug keyed by a flat side, a trapezoid D-sub 25 shell with its pins,
and a tall SSD-like card with a key notch. Each socket is a cavity whose walls sit exactly `CLEARANCE`
outside the plug's cross-section on every side (1 mm in total across the plug), built from boxes whose
inner faces are the edges of the offset outline.

Plug design frame: origin at the plug's centre of mass, z along the insertion axis (the plug goes in
along -z). `seat` is the centre of the plug's face that stops it when it is fully inserted (the bottom
of the round insert or of the card; the shoulder of the D-sub, whose pins hang into the cavity).
Socket frame: origin at the centre of the cavity's mouth, z up; `seat_depth` is how far below the mouth
the plug's seat face rests when it is fully inserted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import Part, box, centre_of_mass, cylinder, prism, shift_parts
from lerobot_taxdpd.sim.poses import quaternion, rot_z
from lerobot_taxdpd.sim.splits import ParameterSpace

CLEARANCE = 0.0005  # per side
WALL = 0.003
FLOOR = 0.003
ARC_SEGMENTS = 24
DSUB_TAPER_DEG = 10.0
PIN_RADIUS = 0.0005
PIN_LENGTH = 0.0012
NOTCH_LAND = 0.0025  # narrowest card left beside the SSD's notch: thinner boxes would not collide reliably

WATERPROOF_SPACE = ParameterSpace(
    name="waterproof",
    ranges={
        "radius": (0.007, 0.011),
        "flat": (0.60, 0.80),
        "insert": (0.008, 0.012),
        "body_extra": (0.002, 0.004),
        "body": (0.014, 0.022),
    },
    keys=("radius", "flat"),
)
DSUB_SPACE = ParameterSpace(
    name="dsub25",
    ranges={"width": (0.036, 0.042), "height": (0.0070, 0.0095), "insert": (0.006, 0.008), "body": (0.010, 0.014)},
    keys=("width", "height"),
)
SSD_SPACE = ParameterSpace(
    name="ssd",
    ranges={
        "width": (0.022, 0.030),
        "thickness": (0.0030, 0.0045),
        "height": (0.055, 0.080),
        "notch": (0.20, 0.35),
        "insert": (0.004, 0.006),
    },
    keys=("width", "height"),
)
SPACES = {"waterproof": WATERPROOF_SPACE, "dsub25": DSUB_SPACE, "ssd": SSD_SPACE}


@dataclass(frozen=True)
class PlugDesign:
    params: dict[str, float]
    parts: tuple[Part, ...]
    seat: np.ndarray  # centre of the face that stops it when fully inserted, design frame
    top: np.ndarray  # centre of the top face, where the gripper holds it


@dataclass(frozen=True)
class SocketDesign:
    parts: tuple[Part, ...]  # socket frame
    seat_depth: float  # the plug's seat face rests this far below the mouth when fully inserted
    mouth_height: float  # height of the mouth above the socket's base (its floor's underside)
    half_extent: float  # radius of a disc that covers the socket's footprint


def offset_polygon(outline: np.ndarray, distance: float) -> np.ndarray:
    """Move every edge of a counter-clockwise convex polygon outwards by `distance`."""
    n = len(outline)
    edges = np.roll(outline, -1, axis=0) - outline
    normals = np.stack([edges[:, 1], -edges[:, 0]], -1) / np.linalg.norm(edges, axis=-1, keepdims=True)
    points = outline + normals * distance  # a point on each offset edge
    result = []
    for i in range(n):
        j = (i - 1) % n  # the edge ending at vertex i
        a = np.column_stack([edges[j], -edges[i]])
        s = np.linalg.solve(a, points[i] - points[j])[0]
        result.append(points[j] + s * edges[j])
    return np.asarray(result)


def cavity_parts(outline: np.ndarray, depth: float) -> list[Part]:
    """Walls and floor of a cavity of cross-section `outline` (convex, counter-clockwise), mouth at z = 0.

    Each wall is a box whose inner face lies on one edge, lengthened past both ends so the corners are
    closed; for a convex outline the lengthened ends stay outside the cavity.
    """
    parts = []
    n = len(outline)
    for i in range(n):
        a, b = outline[i], outline[(i + 1) % n]
        edge = b - a
        length = float(np.linalg.norm(edge))
        outward = np.array([edge[1], -edge[0]]) / length
        centre = (a + b) / 2 + outward * WALL / 2
        angle = np.arctan2(edge[1], edge[0])
        parts.append(
            box((length / 2 + WALL, WALL / 2, depth / 2), (centre[0], centre[1], -depth / 2), quaternion(rot_z(angle)))
        )
    reach = float(np.abs(outline).max()) + 2 * WALL
    parts.append(box((reach, reach, FLOOR / 2), (0.0, 0.0, -depth - FLOOR / 2)))
    return parts


def _finish_plug(params: dict[str, float], parts: list[Part], seat_z: float, top_z: float) -> PlugDesign:
    """Shift a plug designed along +z from z = 0 so that its frame is its centre of mass."""
    com = centre_of_mass([p for p in parts if p.collides])
    seat, top = np.array([0.0, 0.0, seat_z]) - com, np.array([0.0, 0.0, top_z]) - com
    return PlugDesign(dict(params), tuple(shift_parts(parts, -com)), seat, top)


def waterproof(params: dict[str, float]) -> tuple[PlugDesign, SocketDesign]:
    """Round plug with a flat side (the key) on +x, and its socket."""
    r = params["radius"]
    beta = np.arccos(params["flat"])
    angles = np.linspace(beta, 2 * np.pi - beta, ARC_SEGMENTS + 1)
    outline = np.stack([r * np.cos(angles), r * np.sin(angles)], -1)
    insert, body = params["insert"], params["body"]
    parts = [
        prism(outline, 0.0, insert),
        cylinder(r + params["body_extra"], body, position=(0.0, 0.0, insert + body / 2)),
    ]
    depth = insert - 0.002  # the floor stops the insert; the wider body stays 2 mm above the mouth
    socket = SocketDesign(
        tuple(cavity_parts(offset_polygon(outline, CLEARANCE), depth)), depth, depth + FLOOR, r + 3 * WALL
    )
    return _finish_plug(params, parts, 0.0, insert + body), socket


def _dsub_outline(width: float, height: float) -> np.ndarray:
    narrow = width - 2 * height * np.tan(np.radians(DSUB_TAPER_DEG))
    return np.array(
        [[-narrow / 2, -height / 2], [narrow / 2, -height / 2], [width / 2, height / 2], [-width / 2, height / 2]]
    )


def dsub25(params: dict[str, float]) -> tuple[PlugDesign, SocketDesign]:
    """Trapezoid D-sub shell with 13 + 12 pins below its face, and its socket.

    The shoulder of the plug's body rests on the socket's walls; the pins are drawn only (the contacts
    they mate with are not modelled), and the cavity is deep enough for them to hang freely.
    """
    width, height, insert, body = params["width"], params["height"], params["insert"], params["body"]
    outline = _dsub_outline(width, height)
    parts = [
        prism(outline, PIN_LENGTH, PIN_LENGTH + insert),
        box((width / 2 + 0.005, height / 2 + 0.004, body / 2), (0.0, 0.0, PIN_LENGTH + insert + body / 2)),
    ]
    narrow = width - 2 * height * np.tan(np.radians(DSUB_TAPER_DEG))
    for row, count, y in ((0, 13, height * 0.2), (1, 12, -height * 0.2)):
        span = (width if row == 0 else narrow) - 0.008
        for x in np.linspace(-span / 2, span / 2, count):
            parts.append(cylinder(PIN_RADIUS, PIN_LENGTH, position=(x, y, PIN_LENGTH / 2), collides=False))
    cavity = PIN_LENGTH + insert + 0.001
    socket = SocketDesign(
        tuple(cavity_parts(offset_polygon(outline, CLEARANCE), cavity)), 0.0, cavity + FLOOR, width / 2 + 3 * WALL
    )
    return _finish_plug(params, parts, PIN_LENGTH + insert, PIN_LENGTH + insert + body), socket


def ssd(params: dict[str, float]) -> tuple[PlugDesign, SocketDesign]:
    """A tall card with a key notch in its bottom edge, and the slot it goes into."""
    width, thickness, height, insert = params["width"], params["thickness"], params["height"], params["insert"]
    notch_w, notch_h = 0.003, 0.004
    notch_x = min(params["notch"] * width, width / 2 - notch_w / 2 - NOTCH_LAND)  # narrow cards, far notches
    half_t = thickness / 2
    left = (notch_x - notch_w / 2 + width / 2) / 2
    right = (width / 2 - notch_x - notch_w / 2) / 2
    parts = [
        box((left, half_t, notch_h / 2), (-width / 2 + left, 0.0, notch_h / 2)),
        box((right, half_t, notch_h / 2), (width / 2 - right, 0.0, notch_h / 2)),
        box((width / 2, half_t, (height - notch_h) / 2), (0.0, 0.0, notch_h + (height - notch_h) / 2)),
    ]
    c = CLEARANCE
    outline = np.array([[-width / 2, -half_t], [width / 2, -half_t], [width / 2, half_t], [-width / 2, half_t]])
    socket_parts = cavity_parts(offset_polygon(outline, c), insert)
    ridge = notch_h - 0.001
    socket_parts.append(box((notch_w / 2 - c, half_t + c, ridge / 2), (notch_x, 0.0, -insert + ridge / 2)))
    socket = SocketDesign(tuple(socket_parts), insert, insert + FLOOR, width / 2 + 3 * WALL)
    return _finish_plug(params, parts, 0.0, height), socket


BUILDERS = {"waterproof": waterproof, "dsub25": dsub25, "ssd": ssd}
