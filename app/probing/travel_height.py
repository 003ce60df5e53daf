"""The highest point of a triangle mesh above many top-view segments at once (exact).

A probe program travels between stations at the part's highest point along each segment
plus a clearance (:mod:`app.probing.program`).  The vertical plane through a segment cuts
each face in a point, a segment or (a face lying in the plane) the face itself; the section
is piecewise linear, so its highest point over the segment lies at a section vertex inside
the segment or where the section leaves it.  Every face is cut exactly; only the faces whose
top-view box shares a grid cell with the segment are looked at (the others cannot lie above
it), found through a uniform grid over the faces' top-view boxes (built once per mesh from
the cached boxes, kept on the mesh), so a board's hundreds of segments cost one vectorised
pass instead of one whole-mesh scan each.  Lengths in mm.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from app.geometry.tolerance import DEGENERATE_LENGTH_MM

__all__ = ["FACE_BOXES", "face_boxes", "segments_top_max"]

FACE_BOXES = "conforma_face_xy_boxes"  # the part cache persists the boxes under this key
_FACE_GRID = "conforma_face_box_grid"
_MAX_CELLS = 1_000_000
_MAX_ENTRIES = 20_000_000
_LARGE_CELLS = 64
_ON_PLANE_MM = 1e-9  # a vertex this close to the cutting plane lies on it
_FLAT_T_MM = 1e-15  # a section piece shorter than this along the segment is a point


class _FaceGrid(NamedTuple):
    """origin (2,), cell mm, shape (nx, ny); CSR cell -> faces: indptr (nx * ny + 1,), faces;
    large: the faces whose box spans more than _LARGE_CELLS cells (a part's flat bottom),
    kept out of the grid and looked at for every segment."""

    origin: np.ndarray
    cell: float
    shape: tuple[int, int]
    indptr: np.ndarray
    faces: np.ndarray
    large: np.ndarray


def face_boxes(mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    """Top-view bounding boxes of every face: lo (F, 2), hi (F, 2) mm (cached on the mesh)."""
    cached: tuple[np.ndarray, np.ndarray] | None = mesh._cache[FACE_BOXES]
    if cached is None:
        xy = mesh.triangles[:, :, :2]
        cached = (xy.min(axis=1), xy.max(axis=1))
        mesh._cache[FACE_BOXES] = cached
    return cached


def _ranges(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, position within its range) of every element of ranges of ``counts``."""
    owner = np.repeat(np.arange(counts.size), counts)
    return owner, np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def _face_grid(mesh: Any) -> _FaceGrid:
    """The uniform grid of the faces' top-view boxes (cached on the mesh)."""
    cached = mesh._cache[_FACE_GRID]
    if isinstance(cached, _FaceGrid):
        return cached
    lo, hi = face_boxes(mesh)
    origin = lo.min(axis=0)
    extent = np.maximum(hi.max(axis=0) - origin, DEGENERATE_LENGTH_MM)
    size = hi - lo
    cell = max(float(np.median(size.max(axis=1))), float(np.sqrt(extent.prod() / _MAX_CELLS)),
               float(extent.max()) / 2048, DEGENERATE_LENGTH_MM)
    while True:
        shape = (int(extent[0] // cell) + 1, int(extent[1] // cell) + 1)
        i0 = np.minimum(((lo - origin) // cell).astype(np.int64), [shape[0] - 1, shape[1] - 1])
        i1 = np.minimum(((hi - origin) // cell).astype(np.int64), [shape[0] - 1, shape[1] - 1])
        span = i1 - i0 + 1
        counts = span[:, 0] * span[:, 1]
        large = counts > _LARGE_CELLS
        counts[large] = 0
        if counts.sum() <= _MAX_ENTRIES:
            break
        cell *= 2.0
    owner, k = _ranges(counts)
    cell_id = (i0[owner, 0] + k // span[owner, 1]) * shape[1] + i0[owner, 1] + k % span[owner, 1]
    order = np.argsort(cell_id, kind="stable")
    indptr = np.concatenate([[0], np.cumsum(np.bincount(cell_id, minlength=shape[0] * shape[1]))])
    grid = _FaceGrid(origin, cell, shape, indptr.astype(np.int64), owner[order].astype(np.int64),
                     np.flatnonzero(large))
    mesh._cache[_FACE_GRID] = grid
    return grid


def _candidates(grid: _FaceGrid, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(segment index, face index) pairs of the faces registered in a cell the segment
    a -> b (m, 2) passes through (a face may be listed more than once)."""
    length = np.linalg.norm(b - a, axis=1)
    pieces = np.maximum(1, np.ceil(length / grid.cell).astype(np.int64))
    seg, k = _ranges(pieces)
    q0 = a[seg] + (k / pieces[seg])[:, None] * (b - a)[seg]
    q1 = a[seg] + ((k + 1) / pieces[seg])[:, None] * (b - a)[seg]
    nx, ny = grid.shape
    top = [nx - 1, ny - 1]
    c0 = np.clip(((np.minimum(q0, q1) - grid.origin) // grid.cell).astype(np.int64), 0, top)
    c1 = np.clip(((np.maximum(q0, q1) - grid.origin) // grid.cell).astype(np.int64), 0, top)
    keys = []  # a piece is at most one cell long: its box spans <= 2 x 2 cells
    for di in (0, 1):
        for dj in (0, 1):
            ci, cj = np.minimum(c0[:, 0] + di, c1[:, 0]), np.minimum(c0[:, 1] + dj, c1[:, 1])
            keys.append(seg * (nx * ny) + ci * ny + cj)
    key = np.unique(np.concatenate(keys))
    seg_of, cell_of = key // (nx * ny), key % (nx * ny)
    starts = grid.indptr[cell_of]
    owner, pos = _ranges(grid.indptr[cell_of + 1] - starts)
    every = np.repeat(np.arange(len(a)), len(grid.large))
    return (np.concatenate([seg_of[owner], every]),
            np.concatenate([grid.faces[starts[owner] + pos], np.tile(grid.large, len(a))]))


def segments_top_max(mesh: Any, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The highest point (mm) of ``mesh`` above each top-view segment a -> b ((m, 2) each),
    over every face (walls and overhangs included); -inf where no face lies above a segment.
    Segments shorter than DEGENERATE_LENGTH_MM: the highest face straight above the point."""
    a = np.atleast_2d(np.asarray(a, dtype=float))[:, :2]
    b = np.atleast_2d(np.asarray(b, dtype=float))[:, :2]
    out = np.full(len(a), -np.inf)
    length = np.linalg.norm(b - a, axis=1)
    point = length < DEGENERATE_LENGTH_MM
    for i in np.flatnonzero(point):
        origin = np.array([[a[i, 0], a[i, 1], mesh.bounds[1][2] + 1.0]])
        loc, _, _ = mesh.ray.intersects_location(origin, np.array([[0.0, 0.0, -1.0]]))
        out[i] = float(loc[:, 2].max()) if len(loc) else -np.inf
    lines = np.flatnonzero(~point)
    if not len(lines) or not len(mesh.faces):
        return out
    seg, face = _candidates(_face_grid(mesh), a[lines], b[lines])
    if not len(seg):
        return out
    u = (b[lines] - a[lines]) / length[lines, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    triangles = np.asarray(mesh.triangles)
    rel = triangles[face, :, :2] - a[lines][seg][:, None, :]
    d = np.einsum("nvk,nk->nv", rel, normal[seg])  # signed distance of each vertex to the plane
    cut = (d.min(axis=1) <= _ON_PLANE_MM) & (d.max(axis=1) >= -_ON_PLANE_MM)  # the plane meets the face
    seg, face, rel, d = seg[cut], face[cut], rel[cut], d[cut]
    t = np.einsum("nvk,nk->nv", rel, u[seg])  # each vertex's position along the segment
    z = triangles[face, :, 2]
    # the section's points: vertices on the plane, and strict crossings of the three edges
    on = np.abs(d) <= _ON_PLANE_MM
    va, vb = np.array([0, 1, 2]), np.array([1, 2, 0])  # each edge's two vertices
    di, dj = d[:, va], d[:, vb]
    cross = ((di < -_ON_PLANE_MM) & (dj > _ON_PLANE_MM)) | ((di > _ON_PLANE_MM) & (dj < -_ON_PLANE_MM))
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(cross, di / (di - dj), 0.0)
    pt = np.concatenate([t, t[:, va] + w * (t[:, vb] - t[:, va])], axis=1)  # (n, 6)
    pz = np.concatenate([z, z[:, va] + w * (z[:, vb] - z[:, va])], axis=1)
    valid = np.concatenate([on, cross], axis=1)
    # a plane meets a triangle in at most three of these points; the section is their convex
    # hull, whose highest point over a window of t lies on a pair of them
    first = np.argsort(~valid, axis=1, kind="stable")[:, :3]
    pt, pz, valid = (np.take_along_axis(x, first, axis=1) for x in (pt, pz, valid))
    best = np.full(len(lines), -np.inf)
    span = length[lines][seg]
    for p, q in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
        ok = valid[:, p] & valid[:, q]
        t0, t1, z0, z1 = pt[:, p], pt[:, q], pz[:, p], pz[:, q]
        lo = np.maximum(np.minimum(t0, t1), 0.0)
        hi = np.minimum(np.maximum(t0, t1), span)
        ok &= lo <= hi
        steep = np.abs(t1 - t0) > _FLAT_T_MM
        with np.errstate(divide="ignore", invalid="ignore"):
            at_lo = np.where(steep, z0 + (lo - t0) / (t1 - t0) * (z1 - z0), np.maximum(z0, z1))
            at_hi = np.where(steep, z0 + (hi - t0) / (t1 - t0) * (z1 - z0), np.maximum(z0, z1))
        top = np.where(ok, np.maximum(at_lo, at_hi), -np.inf)
        np.maximum.at(best, seg, top)
    out[lines] = best
    return out
