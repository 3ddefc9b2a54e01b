"""Procedural cans and a two-shelf cabinet: stacks of cans below, an open shelf with a row of cans above.

Cabinet frame: origin under the centre of the cabinet's floor, x across, y from the open front (-y) to
the back (+y), z up. The lower compartment is just too low for a stack of three cans, so only stacks of
one can take another; the upper shelf has a row of spots at a fixed pitch, some of them taken.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import Part, box, cylinder
from lerobot_taxdpd.sim.splits import ParameterSpace

CAN_SPACE = ParameterSpace(
    name="can",
    ranges={"radius": (0.028, 0.040), "height": (0.075, 0.120)},
    keys=("radius", "height"),
)
CABINET_SPACE = ParameterSpace(
    name="cabinet",
    ranges={
        "width": (0.40, 0.52),
        "depth": (0.22, 0.28),
        "wall": (0.012, 0.018),
        "lower_headroom": (0.015, 0.030),  # height above a two-can stack
        "upper_headroom": (0.030, 0.060),  # height above a can on the upper shelf
    },
    keys=("width", "depth"),
)
CAN_GAP = 0.01  # minimum distance between neighbouring cans
BACK_GAP = 0.01


@dataclass(frozen=True)
class Support:
    """Where a can may be put: on top of a stack, or at a free spot of the upper shelf (cabinet frame)."""

    label: str
    centre: np.ndarray  # the spot's centre, on the supporting surface
    stack: int | None  # index of the stack whose top can carries it, None for the shelf


@dataclass(frozen=True)
class CabinetDesign:
    params: dict[str, float]
    parts: tuple[Part, ...]
    stacks: tuple[tuple[np.ndarray, int], ...]  # (centre of the stack's base, number of cans)
    shelf_cans: tuple[np.ndarray, ...]  # base centres of the cans standing on the upper shelf
    supports: tuple[Support, ...]
    upper_floor_z: float
    interior_x: tuple[float, float]
    interior_y: tuple[float, float]


def can_parts(radius: float, height: float) -> tuple[Part, ...]:
    """A can centred on its own frame's origin, axis along z."""
    return (cylinder(radius, height),)


def cabinet_design(params: dict[str, float], can: dict[str, float], rng: np.random.Generator) -> CabinetDesign:
    """A cabinet with 2-3 stacks (1 or 2 cans, at least one single) below and a partly filled shelf above."""
    r, h = can["radius"], can["height"]
    w, d, t = params["width"], params["depth"], params["wall"]
    lower = 2 * h + params["lower_headroom"]
    upper = h + params["upper_headroom"]
    upper_floor = t + lower + t
    top = upper_floor + upper
    parts: list[Part] = [
        box((w / 2, d / 2, t / 2), (0.0, 0.0, t / 2)),
        box((w / 2, d / 2, t / 2), (0.0, 0.0, t + lower + t / 2)),
        box((w / 2, d / 2, t / 2), (0.0, 0.0, top + t / 2)),
        box((w / 2, t / 2, (top + t) / 2), (0.0, d / 2 - t / 2, (top + t) / 2)),
        box((t / 2, d / 2, (top + t) / 2), (-w / 2 + t / 2, 0.0, (top + t) / 2)),
        box((t / 2, d / 2, (top + t) / 2), (w / 2 - t / 2, 0.0, (top + t) / 2)),
    ]
    x_low, x_high = -w / 2 + t, w / 2 - t
    row_y = d / 2 - t - BACK_GAP - r
    pitch = 2 * r + CAN_GAP + 0.02
    spots = int((x_high - x_low - CAN_GAP) // pitch)
    first = x_low + (x_high - x_low - (spots - 1) * pitch) / 2
    xs = first + pitch * np.arange(spots)

    # Lower compartment: stacks on some of the spots, at least one of them a single can.
    num_stacks = min(int(rng.integers(2, 4)), spots)
    stack_spots = np.sort(rng.choice(spots, size=num_stacks, replace=False))
    heights = rng.integers(1, 3, size=num_stacks)
    heights[rng.integers(num_stacks)] = 1
    stacks, supports = [], []
    for index, (spot, count) in enumerate(zip(stack_spots, heights, strict=True)):
        base = np.array([xs[spot], row_y, t])
        stacks.append((base, int(count)))
        for level in range(int(count)):
            parts.append(cylinder(r, h, position=(base[0], base[1], t + h * (level + 0.5))))
        if count == 1:
            supports.append(Support(f"stack {index}", base + np.array([0.0, 0.0, h]), index))

    # Upper shelf: cans on some spots, the others free.
    taken = rng.random(spots) < 0.5
    if taken.all():
        taken[rng.integers(spots)] = False
    shelf_cans = []
    for spot in range(spots):
        centre = np.array([xs[spot], row_y, upper_floor])
        if taken[spot]:
            shelf_cans.append(centre)
            parts.append(cylinder(r, h, position=(centre[0], centre[1], upper_floor + h / 2)))
        else:
            supports.append(Support(f"shelf spot {spot}", centre, None))
    return CabinetDesign(
        dict(params),
        tuple(parts),
        tuple(stacks),
        tuple(shelf_cans),
        tuple(supports),
        upper_floor,
        (x_low, x_high),
        (-d / 2, d / 2 - t),
    )
