"""Train and held-out test geometry distributions that never overlap.

Every procedural family (mugs, racks, books, connectors, ...) is described by named parameter ranges.
Two of them are the family's *split keys*. Their unit square is cut into a 4 x 4 checkerboard: train
shapes come from one colour, test shapes from the other, and a margin on each side of every cell edge
is left empty. Both splits therefore span the same overall ranges (the test is about unseen shapes,
not extrapolation), while any test shape differs from any training shape by at least
`2 * SPLIT_MARGIN` of a key parameter's range. The other parameters are drawn from their full ranges.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

SPLITS = ("train", "test")
CELLS = 4
SPLIT_MARGIN = 0.03


@dataclass(frozen=True)
class ParameterSpace:
    """Named uniform ranges of one family; `keys` are the two parameters that decide the split."""

    name: str
    ranges: Mapping[str, tuple[float, float]]
    keys: tuple[str, str]

    def __post_init__(self) -> None:
        for key in self.keys:
            if key not in self.ranges:
                raise ValueError(f"{self.name}: split key {key!r} is not one of its parameters")
        for param, (low, high) in self.ranges.items():
            if not high > low:
                raise ValueError(f"{self.name}: range of {param!r} must have high > low, got ({low}, {high})")

    def unit_keys(self, params: Mapping[str, float]) -> np.ndarray:
        """The split keys of `params` scaled to [0, 1]."""
        return np.array([(params[k] - self.ranges[k][0]) / (self.ranges[k][1] - self.ranges[k][0]) for k in self.keys])

    def split_of(self, params: Mapping[str, float]) -> str | None:
        """'train', 'test', or None when the keys fall in the empty margin between cells."""
        unit = self.unit_keys(params)
        scaled = unit * CELLS
        cell = np.clip(np.floor(scaled), 0, CELLS - 1)
        inner = scaled - cell
        if np.any(inner < SPLIT_MARGIN * CELLS) or np.any(inner > 1 - SPLIT_MARGIN * CELLS):
            return None
        return SPLITS[int(cell.sum()) % 2]

    def sample(self, rng: np.random.Generator, split: str) -> dict[str, float]:
        """Draw one parameter set of `split` (rejection sampling of the split keys)."""
        check_split(split)
        params = {name: float(rng.uniform(low, high)) for name, (low, high) in self.ranges.items()}
        while self.split_of(params) != split:
            for key in self.keys:
                low, high = self.ranges[key]
                params[key] = float(rng.uniform(low, high))
        return params


def check_split(split: str) -> str:
    """Return `split` if it names a geometry split, else raise naming the argument."""
    if split not in SPLITS:
        raise ValueError(f"split: must be one of {SPLITS}, got {split!r}")
    return split
