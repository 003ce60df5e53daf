"""The edge grid finds every crossing of a segment with a projected mesh edge: the same
crossings as testing the segment against every edge, with each edge listed only in the
cells it passes through."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.edge_grid import edge_grid, segment_edge_crossings
from app.geometry.tolerance import ROUNDOFF_REL, ROUNDOFF_SLACK
from app.reference.boards import dome_part


def _all_pairs_crossings(a: np.ndarray, b: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> set[tuple[int, float]]:
    """(segment index, t) of every crossing, every segment p0 -> p1 (m, 2) against every edge
    a -> b (E, 2), with the crossing test of :func:`segment_edge_crossings` (no grid)."""
    out: set[tuple[int, float]] = set()
    e = b - a
    e_len = np.linalg.norm(e, axis=1)
    for i in range(len(p0)):
        r = p1[i] - p0[i]
        qp = a - p0[i]
        denom = r[0] * e[:, 1] - r[1] * e[:, 0]
        ok = np.abs(denom) > ROUNDOFF_REL * np.linalg.norm(r) * e_len
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (qp[:, 0] * e[:, 1] - qp[:, 1] * e[:, 0]) / denom
            s = (qp[:, 0] * r[1] - qp[:, 1] * r[0]) / denom
        ok &= (t > 0) & (t < 1) & (s >= -ROUNDOFF_SLACK) & (s <= 1 + ROUNDOFF_SLACK)
        out.update((i, float(v)) for v in t[ok])
    return out


def _segments(rng: np.random.Generator, mesh: trimesh.Trimesh, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Random top-view segments over the mesh, 1 um to 30 mm long; a third start at a mesh
    vertex, a third run along the axes (on grid lines of a gridded mesh)."""
    lo, hi = mesh.bounds[0, :2], mesh.bounds[1, :2]
    p0 = rng.uniform(lo, hi, (count, 2))
    p0[: count // 3] = mesh.vertices[rng.integers(len(mesh.vertices), size=count // 3), :2]
    p1 = p0 + rng.normal(size=(count, 2)) * 10.0 ** rng.uniform(-3, 1.5, (count, 1))
    p1[count // 3: 2 * count // 3, 1] = p0[count // 3: 2 * count // 3, 1]
    keep = np.linalg.norm(p1 - p0, axis=1) > 1e-6
    return p0[keep], p1[keep]


@pytest.mark.parametrize("name", ["dome", "cylinder", "icosphere"])
def test_the_grid_finds_exactly_the_crossings_of_every_edge(name: str) -> None:
    mesh = {"dome": lambda: dome_part().mesh(grid_mm=4.0),  # a gridded top over a bottom fan of long edges
            "cylinder": lambda: trimesh.creation.cylinder(radius=20.0, height=30.0, sections=48),
            "icosphere": lambda: trimesh.creation.icosphere(subdivisions=3, radius=25.0)}[name]()
    grid = edge_grid(mesh)
    p0, p1 = _segments(np.random.default_rng(7), mesh, 600)
    s_idx, t = segment_edge_crossings(grid, p0, p1)
    found = set(zip(s_idx.tolist(), t.tolist()))
    expected = _all_pairs_crossings(grid.a, grid.b, p0, p1)
    assert len(expected) > 300
    assert found == expected


def test_a_long_edge_is_listed_in_the_cells_it_crosses_not_its_whole_box() -> None:
    part = dome_part()
    mesh = part.mesh(grid_mm=2.0)
    grid = edge_grid(mesh)
    lengths = np.linalg.norm(grid.b - grid.a, axis=1)
    longest = int(np.argmax(lengths))  # a bottom fan edge across the part
    cells_listing_it = int(np.count_nonzero(grid.edges == longest))
    box = np.abs(grid.b[longest] - grid.a[longest]) / grid.cell + 1
    assert lengths[longest] > 20 * grid.cell
    assert cells_listing_it <= 2 * (lengths[longest] / grid.cell + 2)  # about one cell per cell length
    assert cells_listing_it < box.prod() / 5
