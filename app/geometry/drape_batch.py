"""Draping many top-view traces at once: the same answer as :func:`app.geometry.drape.drape_polyline`
per trace, with one edge-crossing search and one ray cast for every trace together.

The per-trace cost of draping is numpy call overhead (tens of small calls per trace); here
every step runs once over all traces' segments, crossings and intervals, and only the
cumulative lengths are taken per trace (a running sum must not run across traces).  Every
value is computed by the same float64 operations as the per-trace path, so the results are
identical.  A batch in which any trace is degenerate or leaves the part returns None: the
caller drapes trace by trace, which names the first bad one.  Lengths in mm.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from app.geometry.drape import DrapedPath, _arrays, _plane_z, _top_faces, _upward_normals
from app.geometry.edge_grid import edge_grid, segment_edge_crossings
from app.geometry.errors import GeometryError
from app.geometry.tolerance import DEFAULT_TOLERANCE, LENGTH_EPS_MM, Tolerance
from app.geometry.validation import as_points

__all__ = ["drape_polylines"]

_CHUNK = 512  # segments per edge-crossing search: its candidate arrays stay in cache


def _starts(groups: np.ndarray) -> np.ndarray:
    """Mask (n,) of the first element of each run of equal values in ``groups`` (n,)."""
    return np.concatenate([[True], groups[1:] != groups[:-1]])


def drape_polylines(mesh: trimesh.Trimesh, xys: Sequence[ArrayLike],
                    tolerance: Tolerance = DEFAULT_TOLERANCE) -> list[DrapedPath] | None:
    """Drape top-view polylines xy (n_i, 2) mm onto the mesh's upper surface, all at once.

    Returns one :class:`~app.geometry.drape.DrapedPath` per polyline, equal to
    ``drape_polyline(mesh, xy, tolerance)``; None when any polyline is not a valid trace
    (bad points, zero length) or is not over the part everywhere (drape those one by one
    for the error)."""
    if not xys:
        return []
    kept: list[np.ndarray] = []
    for xy in xys:
        try:
            pts = as_points(xy, "xy", dims=(2,), min_count=2)
        except GeometryError:
            return None
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        pts = pts[np.concatenate([[True], seg > tolerance.dedup_mm])]
        if pts.shape[0] < 2:
            return None
        kept.append(pts)
    n_seg = np.array([p.shape[0] - 1 for p in kept])
    p0 = np.concatenate([p[:-1] for p in kept])
    p1 = np.concatenate([p[1:] for p in kept])
    trace_of_seg = np.repeat(np.arange(len(kept)), n_seg)
    last_seg = np.cumsum(n_seg) - 1
    m = _arrays(mesh)
    grid = edge_grid(mesh)
    found = [segment_edge_crossings(grid, p0[lo:lo + _CHUNK], p1[lo:lo + _CHUNK])
             for lo in range(0, p0.shape[0], _CHUNK)]
    s_idx = np.concatenate([c[0] + lo for c, lo in zip(found, range(0, p0.shape[0], _CHUNK))])
    t = np.concatenate([c[1] for c in found])
    seg_id = np.concatenate([np.arange(p0.shape[0]), s_idx, last_seg])
    tt = np.concatenate([np.zeros(p0.shape[0]), t, np.ones(len(kept))])
    order = np.lexsort((tt, seg_id))
    seg_id, tt = seg_id[order], tt[order]
    q = p0[seg_id] + tt[:, None] * (p1 - p0)[seg_id]
    trace = trace_of_seg[seg_id]
    step = np.linalg.norm(np.diff(q, axis=0), axis=1)
    distinct = np.concatenate([[True], step > LENGTH_EPS_MM]) | _starts(trace)
    q, trace = q[distinct], trace[distinct]
    first = np.flatnonzero(_starts(trace))
    last = np.append(first[1:] - 1, q.shape[0] - 1)
    q[last] = np.array([p[-1] for p in kept])
    # intervals: consecutive points of one trace
    inside = trace[:-1] == trace[1:]
    qa, qb = q[:-1][inside], q[1:][inside]
    faces = _top_faces(m, 0.5 * (qa + qb))
    if (faces < 0).any():
        return None
    z_left = _plane_z(m, faces, qa)
    z_right = _plane_z(m, faces, qb)
    n_face = _upward_normals(m, faces)
    trace_of_interval = trace[:-1][inside]
    # inner vertices: the end of an interval that is the start of the next one of the same trace
    joined = trace_of_interval[:-1] == trace_of_interval[1:]
    inner_xy = qb[:-1][joined]
    zr, zl = z_right[:-1][joined], z_left[1:][joined]
    nl, nr = n_face[:-1][joined], n_face[1:][joined]
    jump = np.abs(zr - zl) > tolerance.dedup_mm
    inner_z = 0.5 * (zr + zl)
    inner_n = nl + nr
    inner_n /= np.linalg.norm(inner_n, axis=1, keepdims=True)
    count = np.where(jump, 2, 1)
    idx = np.repeat(np.arange(inner_xy.shape[0]), count)
    second = np.concatenate([[False], idx[1:] == idx[:-1]])
    z_inner = np.where(jump[idx], np.where(second, zl[idx], zr[idx]), inner_z[idx])
    n_inner = np.where(jump[idx, None], np.where(second[:, None], nr[idx], nl[idx]), inner_n[idx])
    trace_of_inner = trace_of_interval[:-1][joined][idx]
    # rows per trace: its start, its inner rows, its end, placed by offsets
    inner_count = np.bincount(trace_of_inner, minlength=len(kept))
    rows = inner_count + 2
    offset = np.concatenate([[0], np.cumsum(rows)])
    inner_first = np.concatenate([[0], np.cumsum(inner_count)])
    at_inner = offset[trace_of_inner] + 1 + (np.arange(idx.size) - inner_first[trace_of_inner])
    interval_first = np.flatnonzero(_starts(trace_of_interval))
    interval_last = np.append(interval_first[1:] - 1, trace_of_interval.size - 1)
    total = int(offset[-1])
    xy_out = np.empty((total, 2))
    z_out = np.empty(total)
    n_out = np.empty((total, 3))
    starts, ends = offset[:-1], offset[1:] - 1
    xy_out[starts], z_out[starts], n_out[starts] = q[first], z_left[interval_first], n_face[interval_first]
    xy_out[at_inner], z_out[at_inner], n_out[at_inner] = inner_xy[idx], z_inner, n_inner
    xy_out[ends], z_out[ends], n_out[ends] = q[last], z_right[interval_last], n_face[interval_last]
    points = np.column_stack([xy_out, z_out])
    step_3d = np.linalg.norm(np.diff(points, axis=0), axis=1)
    step_xy = np.linalg.norm(p1 - p0, axis=1)
    seg_offset = np.concatenate([[0], np.cumsum(n_seg)])
    out = []
    for i in range(len(kept)):
        lo, hi = int(offset[i]), int(offset[i + 1])
        s = np.concatenate([[0.0], np.cumsum(step_3d[lo:hi - 1])])
        xy_len = float(step_xy[seg_offset[i]:seg_offset[i + 1]].sum())
        out.append(DrapedPath(points[lo:hi], n_out[lo:hi], s, xy_len, float(s[-1]), float(s[-1] / xy_len)))
    return out
