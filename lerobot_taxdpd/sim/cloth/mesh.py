"""Procedural cloth: a node grid with rectangular holes, following DEDO's HangProcCloth generator rules.

Grid node (i, j) has lateral index i (0 = gripper-0 side) and row j (0 = top edge, where both grippers
hold the corners). A hole is an inclusive block of removed nodes; every quad whose four nodes survive
becomes two triangles. DEDO's rules: a hole spans 1 to round(0.3 n) extra nodes per side, every hole index
lies strictly inside (2, n - 3), and two holes keep at least 3 nodes between them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_taxdpd.maths.geometry import farthest_point_indices

MIN_EDGE_INDEX = 3  # hole indices lie in [3, n - 4]: at least two rows of faces around every hole
MIN_HOLE_GAP = 3  # nodes between two holes
MAX_HOLE_TRIES = 1000


@dataclass(frozen=True)
class Hole:
    """Removed nodes x0..x1 (lateral) by y0..y1 (rows), inclusive."""

    x0: int
    x1: int
    y0: int
    y1: int

    def contains(self, i: int, j: int) -> bool:
        return self.x0 <= i <= self.x1 and self.y0 <= j <= self.y1

    def overlaps(self, other: Hole, gap: int = MIN_HOLE_GAP) -> bool:
        """True when the holes are closer than `gap` nodes in both directions (DEDO's overlap rule)."""
        return (
            self.x0 < other.x1 + gap
            and self.x1 > other.x0 - gap
            and self.y0 < other.y1 + gap
            and self.y1 > other.y0 - gap
        )


def hole_is_valid(hole: Hole, node_density: int) -> bool:
    low, high = MIN_EDGE_INDEX, node_density - 1 - MIN_EDGE_INDEX
    return all(low <= v <= high for v in (hole.x0, hole.x1, hole.y0, hole.y1))


def sample_holes(rng: np.random.Generator, node_density: int, num_holes: int, accept=None) -> list[Hole]:
    """Rejection-sample `num_holes` holes under DEDO's rules; `accept(hole)` may add a split constraint."""
    if num_holes not in (1, 2):
        raise ValueError(f"num_holes: must be 1 or 2, got {num_holes}")
    max_extra = max(2, int(round(0.3 * node_density)))
    for _ in range(MAX_HOLE_TRIES):
        holes = []
        for _ in range(num_holes):
            x0 = int(rng.integers(2, node_density - 2))
            y0 = int(rng.integers(2, node_density - 2))
            holes.append(Hole(x0, x0 + int(rng.integers(1, max_extra)), y0, y0 + int(rng.integers(1, max_extra))))
        if not all(hole_is_valid(h, node_density) and (accept is None or accept(h)) for h in holes):
            continue
        if num_holes == 2 and holes[0].overlaps(holes[1]):
            continue
        return holes
    raise RuntimeError(f"could not place {num_holes} holes on a {node_density}-node grid in {MAX_HOLE_TRIES} tries")


@dataclass
class ClothMesh:
    """Rest-state triangle mesh of the cloth in its own frame: x lateral, z up, top edge at z = 0."""

    vertices: np.ndarray  # (V, 3), simulation order
    faces: np.ndarray  # (F, 3) int, two triangles per kept quad
    grid_index: np.ndarray  # (n, n) vertex id of node (i, j), -1 where removed
    corner_vertices: tuple[int, int]  # vertices the two grippers hold: nodes (0, 0) and (n - 1, 0)
    hole_loops: list[np.ndarray]  # per hole: vertex ids of the ring of kept nodes around it, in order


def build_cloth_mesh(node_density: int, width: float, height: float, holes: list[Hole]) -> ClothMesh:
    """Triangulate the grid, leaving out the holes' nodes and every quad that touches them."""
    n = node_density
    keep = np.ones((n, n), dtype=bool)
    for hole in holes:
        if not hole_is_valid(hole, n):
            raise ValueError(f"holes: {hole} leaves fewer than {MIN_EDGE_INDEX} nodes to an edge of a {n}-node grid")
        keep[hole.x0 : hole.x1 + 1, hole.y0 : hole.y1 + 1] = False
    grid_index = np.full((n, n), -1, dtype=np.int64)
    grid_index[keep] = np.arange(int(keep.sum()))
    ii, jj = np.nonzero(keep)  # row-major over (i, j): the same order as grid_index
    vertices = np.stack(
        [width * (ii / (n - 1) - 0.5), np.zeros(len(ii)), -height * jj / (n - 1)], axis=1
    ).astype(np.float64)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = grid_index[i, j], grid_index[i + 1, j], grid_index[i, j + 1], grid_index[i + 1, j + 1]
            if min(a, b, c, d) < 0:
                continue
            faces.append((a, c, b))
            faces.append((c, d, b))
    loops = [grid_index[ring] for ring in (_ring_nodes(h) for h in holes)]
    return ClothMesh(
        vertices=vertices,
        faces=np.asarray(faces, dtype=np.int64),
        grid_index=grid_index,
        corner_vertices=(int(grid_index[0, 0]), int(grid_index[n - 1, 0])),
        hole_loops=loops,
    )


def _ring_nodes(hole: Hole) -> tuple[np.ndarray, np.ndarray]:
    """Grid indices of the closed ring of nodes bordering a hole (the mesh boundary loop), in order."""
    i0, i1, j0, j1 = hole.x0 - 1, hole.x1 + 1, hole.y0 - 1, hole.y1 + 1
    top = [(i, j0) for i in range(i0, i1)]
    right = [(i1, j) for j in range(j0, j1)]
    bottom = [(i, j1) for i in range(i1, i0, -1)]
    left = [(i0, j) for j in range(j1, j0, -1)]
    ring = np.asarray(top + right + bottom + left)
    return ring[:, 0], ring[:, 1]


def write_obj(path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Wavefront OBJ as pybullet's soft-body loader reads it (1-based faces, vertex order kept)."""
    with open(path, "w") as f:
        f.writelines(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)


@dataclass
class SurfaceSamples:
    """Fixed points on the cloth surface: triangle ids and barycentric weights.

    Evaluated on any deformed copy of the mesh they give the same material points, so row i of the start
    cloud and row i of the goal cloud are the same bit of cloth (the correspondence the goal predictor needs).
    """

    triangles: np.ndarray  # (N,) int
    weights: np.ndarray  # (N, 3)

    def points(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        corners = vertices[faces[self.triangles]]  # (N, 3, 3)
        return np.einsum("nk,nkd->nd", self.weights, corners)


def sample_surface(
    mesh: ClothMesh, num_points: int, rng: np.random.Generator, oversample: int = 8
) -> SurfaceSamples:
    """Area-weighted random surface points, thinned by farthest point sampling for even coverage."""
    corners = mesh.vertices[mesh.faces]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    count = num_points * oversample
    triangles = rng.choice(len(mesh.faces), size=count, p=areas / areas.sum())
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    weights = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)
    candidates = SurfaceSamples(triangles, weights)
    keep = farthest_point_indices(candidates.points(mesh.vertices, mesh.faces), num_points)
    return SurfaceSamples(triangles[keep], weights[keep])
