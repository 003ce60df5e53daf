"""A uniform 2-D grid over a mesh's projected (top-view) edges, for exact draping.

The grid finds, for each segment of a top-view polyline, every mesh edge whose XY
projection it crosses.  Built once per mesh (cached on the trimesh object, invalidated by
trimesh when the mesh changes).  A service may persist a grid (:func:`edge_grid_arrays`)
and give it back to a later process's mesh (:func:`edge_grid_from_arrays`,
:func:`attach_edge_grid`) instead of rebuilding it.  Lengths in mm.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import trimesh

from app.geometry.tolerance import DEGENERATE_LENGTH_MM, LENGTH_EPS_MM, ROUNDOFF_REL, ROUNDOFF_SLACK, VERTICAL_NZ

__all__ = ["EdgeGrid", "attach_edge_grid", "cached_edge_grid", "edge_grid", "edge_grid_arrays",
           "edge_grid_from_arrays", "segment_edge_crossings"]

_CACHE_KEY = "conforma_edge_grid"
_MAX_CELLS = 4_000_000
_MAX_ENTRIES = 40_000_000
_MARGIN_CELLS = 1e-6  # an edge is registered in every cell within this fraction of a cell (plus:)
_MARGIN_REL = 1e-9  # this fraction of its extent
_STEEP_CELLS = 1e-3  # an edge narrower than this fraction of a cell takes its whole box


class EdgeGrid(NamedTuple):
    """a, b: (E, 2) projected edge ends; origin (2,), cell (mm), shape (nx, ny); CSR cell -> edges
    (indptr (nx * ny + 1,) and edges (entries,), int32: entries <= _MAX_ENTRIES < 2**31)."""

    a: np.ndarray
    b: np.ndarray
    origin: np.ndarray
    cell: float
    shape: tuple[int, int]
    indptr: np.ndarray
    edges: np.ndarray


def _expand_ranges(starts: np.ndarray | None, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ranges (start, count): (owner index, position within range) of every element."""
    owner = np.repeat(np.arange(counts.size), counts)
    offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    return owner, starts[owner] + offset if starts is not None else offset


def edge_grid(mesh: trimesh.Trimesh) -> EdgeGrid:
    """The (cached) grid of the projected edges of every non-vertical face of ``mesh``."""
    cached = cached_edge_grid(mesh)
    if cached is not None:
        return cached
    faces = mesh.faces[np.abs(mesh.face_normals[:, 2]) > VERTICAL_NZ]
    pairs = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1).astype(np.int64)
    keys = np.sort(pairs[:, 0] * len(mesh.vertices) + pairs[:, 1])
    keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]  # shared edges once
    v0, v1 = keys // len(mesh.vertices), keys % len(mesh.vertices)
    a, b = mesh.vertices[v0, :2], mesh.vertices[v1, :2]
    keep = np.linalg.norm(b - a, axis=1) > DEGENERATE_LENGTH_MM
    a, b = a[keep], b[keep]
    lo = np.minimum(a, b).min(axis=0) if a.size else np.zeros(2)
    hi = np.maximum(a, b).max(axis=0) if a.size else np.ones(2)
    extent = np.maximum(hi - lo, LENGTH_EPS_MM)
    mean_len = float(np.linalg.norm(b - a, axis=1).mean()) if a.size else float(extent.max())
    cell = max(mean_len, float(np.sqrt(extent.prod() / _MAX_CELLS)), float(extent.max()) / 4096)
    while True:
        shape = (int(extent[0] // cell) + 1, int(extent[1] // cell) + 1)
        found = _traversed_cells(a, b, lo, cell, shape)
        if found is not None:
            break
        cell *= 2.0
    owner, cell_id = found
    order = np.argsort(cell_id, kind="stable")
    indptr = np.concatenate([[0], np.cumsum(np.bincount(cell_id, minlength=shape[0] * shape[1]))])
    grid = EdgeGrid(a, b, lo, cell, shape, indptr.astype(np.int32), owner[order].astype(np.int32))
    attach_edge_grid(mesh, grid)
    return grid


def _traversed_cells(a: np.ndarray, b: np.ndarray, lo: np.ndarray, cell: float,
                     shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """The cells each edge a -> b (E, 2) passes through or comes within a margin of
    (``_MARGIN_CELLS`` of a cell plus ``_MARGIN_REL`` of the edge, far beyond round-off and
    the crossing test's slack at the edge's ends): (edge index (n,), cell id (n,)), or None
    when there would be more than ``_MAX_ENTRIES``.

    Column by column of the grid: the edge's y range over the column's x range (widened by
    the margin) gives the rows.  An edge of a cell's length meets 2-3 cells where its
    bounding box would give it as many as the box covers (a long diagonal edge: thousands),
    so a query finds the same crossings among far fewer candidates.  Nearly vertical edges
    (x extent under ``_STEEP_CELLS`` of a cell) take the rows of their whole box."""
    nx, ny = shape
    mn, mx = np.minimum(a, b), np.maximum(a, b)
    d = b - a
    margin = _MARGIN_CELLS * cell + _MARGIN_REL * np.abs(d).max(axis=1, keepdims=True)
    i0 = np.clip(((mn - margin - lo) // cell).astype(np.int64), 0, [nx - 1, ny - 1])
    i1 = np.clip(((mx + margin - lo) // cell).astype(np.int64), 0, [nx - 1, ny - 1])
    columns = i1[:, 0] - i0[:, 0] + 1
    if columns.sum() > _MAX_ENTRIES:
        return None
    edge, k = _expand_ranges(None, columns)
    ix = i0[edge, 0] + k
    m = margin[edge, 0]
    x_lo = np.maximum(lo[0] + ix * cell - m, mn[edge, 0])
    x_hi = np.minimum(lo[0] + (ix + 1) * cell + m, mx[edge, 0])
    dx, dy = d[edge, 0], d[edge, 1]
    steep = np.abs(dx) < _STEEP_CELLS * cell
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo = np.clip((x_lo - a[edge, 0]) / dx, 0.0, 1.0)
        t_hi = np.clip((x_hi - a[edge, 0]) / dx, 0.0, 1.0)
    y_lo = a[edge, 1] + np.minimum(t_lo, t_hi) * dy
    y_hi = a[edge, 1] + np.maximum(t_lo, t_hi) * dy
    y_lo, y_hi = np.where(dy >= 0, y_lo, y_hi), np.where(dy >= 0, y_hi, y_lo)
    with np.errstate(divide="ignore", invalid="ignore"):  # the round-off of t, times the edge's slope
        m_y = m + np.where(steep, 0.0, np.abs(dy) * 1e-15 * (np.abs(a[edge, 0]) + np.abs(x_hi) + cell) / np.abs(dx))
    y_lo = np.where(steep, mn[edge, 1], y_lo) - m_y
    y_hi = np.where(steep, mx[edge, 1], y_hi) + m_y
    row0 = np.clip(((y_lo - lo[1]) // cell).astype(np.int64), i0[edge, 1], i1[edge, 1])
    row1 = np.clip(((y_hi - lo[1]) // cell).astype(np.int64), i0[edge, 1], i1[edge, 1])
    rows = row1 - row0 + 1
    if rows.sum() > _MAX_ENTRIES:
        return None
    column, r = _expand_ranges(None, rows)
    return edge[column], ix[column] * ny + row0[column] + r


def cached_edge_grid(mesh: trimesh.Trimesh) -> EdgeGrid | None:
    """The grid already built on (or attached to) ``mesh``, else None."""
    cached = mesh._cache[_CACHE_KEY]  # trimesh's cache returns None for a missing key
    return cached if isinstance(cached, EdgeGrid) else None


def attach_edge_grid(mesh: trimesh.Trimesh, grid: EdgeGrid) -> None:
    """Give ``mesh`` its grid (built by :func:`edge_grid` on this very mesh, possibly in
    another process); trimesh drops it when the mesh changes."""
    mesh._cache[_CACHE_KEY] = grid


def edge_grid_arrays(grid: EdgeGrid) -> dict[str, np.ndarray]:
    """The grid as named arrays (to store): a, b (E, 2), origin (2,), cell (1,), shape (2,),
    indptr, edges."""
    return {"a": grid.a, "b": grid.b, "origin": np.asarray(grid.origin, dtype=float),
            "cell": np.array([grid.cell]), "shape": np.array(grid.shape, dtype=np.int64),
            "indptr": grid.indptr, "edges": grid.edges}


def edge_grid_from_arrays(arrays: dict[str, np.ndarray]) -> EdgeGrid:
    """The grid from :func:`edge_grid_arrays`'s output.  Raises ValueError when the arrays
    do not form a grid (wrong shapes or an index out of range)."""
    a, b, indptr, edges = arrays["a"], arrays["b"], arrays["indptr"], arrays["edges"]
    shape = (int(arrays["shape"][0]), int(arrays["shape"][1]))
    if (a.ndim != 2 or a.shape[1] != 2 or b.shape != a.shape or indptr.shape != (shape[0] * shape[1] + 1,)
            or int(indptr[-1]) != len(edges) or (len(edges) and int(edges.max()) >= len(a))):
        raise ValueError("the arrays do not form an edge grid")
    return EdgeGrid(a, b, np.asarray(arrays["origin"], dtype=float), float(arrays["cell"][0]), shape, indptr, edges)


def segment_edge_crossings(grid: EdgeGrid, p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Crossings of segments p0 -> p1 (m, 2) with the grid's edges.

    Returns (segment index (c,), t (c,) in (0, 1) along the segment); duplicates possible.
    """
    seg_len = np.linalg.norm(p1 - p0, axis=1)
    pieces = np.maximum(1, np.ceil(seg_len / grid.cell).astype(np.int64))
    seg, k = _expand_ranges(None, pieces)
    f0, f1 = k / pieces[seg], (k + 1) / pieces[seg]
    q0 = p0[seg] + f0[:, None] * (p1 - p0)[seg]
    q1 = p0[seg] + f1[:, None] * (p1 - p0)[seg]
    nx, ny = grid.shape
    c0 = np.clip(((np.minimum(q0, q1) - grid.origin) // grid.cell).astype(np.int64), 0, [nx - 1, ny - 1])
    c1 = np.clip(((np.maximum(q0, q1) - grid.origin) // grid.cell).astype(np.int64), 0, [nx - 1, ny - 1])
    # each piece is at most one cell long, so its bounding box spans <= 2 x 2 cells
    cand = []
    for di in (0, 1):
        for dj in (0, 1):
            ci, cj = np.minimum(c0[:, 0] + di, c1[:, 0]), np.minimum(c0[:, 1] + dj, c1[:, 1])
            cand.append(seg * (nx * ny) + ci * ny + cj)
    key = np.unique(np.concatenate(cand))
    seg_of, cell_of = key // (nx * ny), key % (nx * ny)
    starts, counts = grid.indptr[cell_of], grid.indptr[cell_of + 1] - grid.indptr[cell_of]
    owner, pos = _expand_ranges(starts, counts)
    s_idx, e_idx = seg_of[owner], grid.edges[pos]
    r = (p1 - p0)[s_idx]
    e = grid.b[e_idx] - grid.a[e_idx]
    qp = grid.a[e_idx] - p0[s_idx]
    denom = r[:, 0] * e[:, 1] - r[:, 1] * e[:, 0]
    ok = np.abs(denom) > ROUNDOFF_REL * np.linalg.norm(r, axis=1) * np.linalg.norm(e, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[:, 0] * e[:, 1] - qp[:, 1] * e[:, 0]) / denom
        s = (qp[:, 0] * r[:, 1] - qp[:, 1] * r[:, 0]) / denom
    ok &= (t > 0) & (t < 1) & (s >= -ROUNDOFF_SLACK) & (s <= 1 + ROUNDOFF_SLACK)
    return s_idx[ok], t[ok]
