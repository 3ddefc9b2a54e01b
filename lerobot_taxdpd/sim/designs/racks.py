"""Procedural mug racks: a base disc, a vertical pole and one or more pegs tilted upwards.

The rack frame has its origin at the centre of the base on the table and z up. Each peg starts on the
pole's axis and sticks out by `peg_length` beyond the pole's surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import Part, cylinder
from lerobot_taxdpd.sim.poses import quaternion, rot_y, rot_z
from lerobot_taxdpd.sim.splits import ParameterSpace

RACK_SPACE = ParameterSpace(
    name="rack",
    ranges={
        "base_radius": (0.060, 0.090),
        "pole_radius": (0.008, 0.012),
        "pole_height": (0.34, 0.40),
        "peg_radius": (0.004, 0.006),
        "peg_length": (0.095, 0.130),
        "peg_elevation_deg": (15.0, 35.0),
    },
    keys=("peg_elevation_deg", "peg_length"),
)
BASE_THICKNESS = 0.012


@dataclass(frozen=True)
class Peg:
    """A peg's axis in the rack frame: from `start` (on the pole's axis) to `tip`."""

    start: np.ndarray
    tip: np.ndarray
    radius: float
    reach: float  # length beyond the pole's surface

    @property
    def direction(self) -> np.ndarray:
        d = self.tip - self.start
        return d / np.linalg.norm(d)


@dataclass(frozen=True)
class RackDesign:
    params: dict[str, float]
    parts: tuple[Part, ...]
    pegs: tuple[Peg, ...]
    pole_radius: float


def sample_peg_layout(rng: np.random.Generator, params: dict[str, float], num_pegs: int) -> list[tuple[float, float]]:
    """(height on the pole, azimuth) of each peg: pegs on roughly opposite sides, 5 cm or more apart."""
    top = params["pole_height"] - 0.02
    if num_pegs == 1:
        return [(float(rng.uniform(0.23, top)), float(rng.uniform(0, 2 * np.pi)))]
    azimuth = float(rng.uniform(0, 2 * np.pi))
    layout = []
    heights = rng.permutation([rng.uniform(0.22, 0.26), rng.uniform(0.29, top)])
    for i in range(num_pegs):
        layout.append((float(heights[i % 2]), azimuth + i * float(rng.uniform(0.75, 1.25)) * np.pi))
    return layout


def rack_design(params: dict[str, float], layout: list[tuple[float, float]]) -> RackDesign:
    """Build a rack's parts and peg axes from its parameters and peg layout."""
    pole_r, pole_h = params["pole_radius"], params["pole_height"]
    peg_r, reach = params["peg_radius"], params["peg_length"]
    elevation = np.radians(params["peg_elevation_deg"])
    parts = [
        cylinder(params["base_radius"], BASE_THICKNESS, position=(0.0, 0.0, BASE_THICKNESS / 2)),
        cylinder(pole_r, pole_h, position=(0.0, 0.0, pole_h / 2)),
    ]
    pegs = []
    for height, azimuth in layout:
        direction = np.array(
            [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
        )
        start = np.array([0.0, 0.0, height])
        length = pole_r + reach
        tip = start + direction * length
        # A cylinder's axis is z: tilt it down from vertical to the peg's elevation, then turn it.
        orientation = rot_z(azimuth) @ rot_y(np.pi / 2 - elevation)
        parts.append(
            cylinder(peg_r, length, position=tuple(start + direction * length / 2), orientation=quaternion(orientation))
        )
        pegs.append(Peg(start, tip, peg_r, reach))
    return RackDesign(dict(params), tuple(parts), tuple(pegs), pole_r)
