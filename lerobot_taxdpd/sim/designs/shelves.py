"""Procedural books and a partly filled, open-topped bookshelf with a few free slots.

Shelf frame: origin under the centre of the base board, x along the row of books, y from the open front
(-y) to the back wall (+y), z up. Books are boxes; in a book's frame x is its thickness, y its depth
(spine at -y) and z its height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.sim.bodies import Part, box
from lerobot_taxdpd.sim.splits import ParameterSpace

BOOK_SPACE = ParameterSpace(
    name="book",
    ranges={"thickness": (0.020, 0.050), "height": (0.150, 0.240), "depth": (0.110, 0.170)},
    keys=("thickness", "height"),
)
SHELF_SPACE = ParameterSpace(
    name="shelf",
    ranges={
        "width": (0.45, 0.62),
        "depth": (0.20, 0.24),
        "board": (0.012, 0.018),
        "wall_height": (0.20, 0.28),
        "clearance": (0.010, 0.020),  # total width a free slot leaves around the book
    },
    keys=("width", "depth"),
)
BACK_GAP = 0.004  # books stand this far in front of the back wall
NEIGHBOUR_THICKNESS = (0.015, 0.050)


@dataclass(frozen=True)
class ShelfDesign:
    params: dict[str, float]
    parts: tuple[Part, ...]
    interior_x: tuple[float, float]
    interior_y: tuple[float, float]
    floor_z: float
    neighbours: tuple[tuple[float, float, float, float], ...]  # (x centre, thickness, depth, height)
    slots: tuple[tuple[float, float], ...]  # free (x low, x high) intervals that fit the object book


def book_parts(thickness: float, depth: float, height: float) -> tuple[Part, ...]:
    """A book centred on its own frame's origin (its centre of mass)."""
    return (box((thickness / 2, depth / 2, height / 2)),)


def shelf_design(
    params: dict[str, float], book: dict[str, float], rng: np.random.Generator, num_slots: int
) -> ShelfDesign:
    """A shelf whose row of neighbour books leaves `num_slots` slots the object `book` fits into.

    Slots are the book's thickness plus `clearance` wide and never adjacent; every other gap in the row
    is at most a few millimetres (1.5 cm at the end of the row), narrower than any book, so the listed
    slots are the only places it fits.
    """
    w, d, t, wall_h = params["width"], params["depth"], params["board"], params["wall_height"]
    parts = [
        box((w / 2, d / 2, t / 2), (0.0, 0.0, t / 2)),
        box((w / 2, t / 2, wall_h / 2), (0.0, d / 2 - t / 2, t + wall_h / 2)),
        box((t / 2, d / 2, wall_h / 2), (-w / 2 + t / 2, 0.0, t + wall_h / 2)),
        box((t / 2, d / 2, wall_h / 2), (w / 2 - t / 2, 0.0, t + wall_h / 2)),
    ]
    x_low, x_high = -w / 2 + t, w / 2 - t
    slot_width = book["thickness"] + params["clearance"]

    # Neighbour books (with gaps of at most 3 mm) fill what the slots leave; the last one takes up the
    # rest, so the only gap left over is narrower than the thinnest book.
    room = x_high - x_low - num_slots * slot_width
    books: list[tuple[float, float]] = []  # (thickness, gap after it)
    while True:
        thickness, gap = rng.uniform(*NEIGHBOUR_THICKNESS), rng.uniform(0.0, 0.003)
        left = room - sum(a + b for a, b in books)
        if thickness + gap > left:
            if left - 0.002 >= NEIGHBOUR_THICKNESS[0]:
                books.append((left - 0.002, 0.002))
            break
        books.append((thickness, gap))
    if len(books) + 1 < num_slots:
        raise ValueError(f"shelf too narrow for {num_slots} slots of {slot_width * 100:.1f} cm")
    # Slots go at distinct places in the row of books, so no two slots touch.
    slot_places = set(rng.choice(len(books) + 1, size=num_slots, replace=False).tolist())
    neighbours, slots = [], []
    x = x_low
    for i in range(len(books) + 1):
        if i in slot_places:
            slots.append((x, x + slot_width))
            x += slot_width
        if i < len(books):
            thickness, gap = books[i]
            height = rng.uniform(0.14, min(0.26, wall_h + 0.06))
            depth = rng.uniform(0.11, d - BACK_GAP - t - 0.005)
            neighbours.append((x + thickness / 2, thickness, depth, height))
            x += thickness + gap
    back = d / 2 - t - BACK_GAP
    for cx, thickness, depth, height in neighbours:
        parts.append(box((thickness / 2, depth / 2, height / 2), (cx, back - depth / 2, t + height / 2)))
    return ShelfDesign(
        dict(params), tuple(parts), (x_low, x_high), (-d / 2, d / 2 - t), t, tuple(neighbours), tuple(slots)
    )
