"""Draping top-view traces onto a part's upper surface (a faceted trimesh mesh).

The upper surface is, at each (x, y), the highest mesh point along -Z.  On a faceted mesh it
is piecewise linear, so draping is *exact* when every crossing of the trace with a
projected triangle edge becomes a vertex: between two consecutive crossings the surface
under the trace is one planar facet.  Each interval's facet is found by one vertical ray
(embree) at its midpoint; z at the interval's ends follows from that facet's plane in
float64.  Where neighbouring facets disagree (a vertical step) both heights are kept.
Lengths in mm.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import trimesh
from numpy.typing import ArrayLike

from app.geometry.edge_grid import edge_grid, segment_edge_crossings
from app.geometry.errors import DegenerateGeometryError, OffSurfaceError
from app.geometry.tolerance import DEFAULT_TOLERANCE, LENGTH_EPS_MM, VERTICAL_NZ, Tolerance
from app.geometry.validation import as_points

# trimesh is untyped: its closest-point query with the types it returns (points (n, 3),
# distances (n,), face indices (n,))
_closest_point: Callable[[trimesh.Trimesh, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]] = \
    trimesh.proximity.closest_point

__all__ = ["DrapedPath", "TopSurface", "SnappedPoints", "top_surface_z", "drape_polyline", "snap_to_surface"]


class TopSurface(NamedTuple):
    """z (n,) mm (NaN where missed), unit upward normals (n, 3), hit (n,) bool."""

    z: np.ndarray
    normals: np.ndarray
    hit: np.ndarray


class DrapedPath(NamedTuple):
    """points (k, 3) mm on the surface, unit normals (k, 3), s_mm (k,) cumulative 3-D length,
    xy_length_mm (top-view length), length_mm (3-D length), slope_stretch = length / xy_length."""

    points: np.ndarray
    normals: np.ndarray
    s_mm: np.ndarray
    xy_length_mm: float
    length_mm: float
    slope_stretch: float


class SnappedPoints(NamedTuple):
    """points (n, 3) closest surface points, normals (n, 3) unit (upward), distance (n,) mm."""

    points: np.ndarray
    normals: np.ndarray
    distance: np.ndarray


class _MeshArrays(NamedTuple):
    """The mesh's arrays, fetched once per call (each trimesh property access re-hashes them)."""

    mesh: trimesh.Trimesh
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    bounds: np.ndarray


def _arrays(mesh: trimesh.Trimesh) -> _MeshArrays:
    return _MeshArrays(
        mesh, mesh.vertices.view(np.ndarray), mesh.faces.view(np.ndarray), mesh.face_normals.view(np.ndarray),
        np.asarray(mesh.bounds),
    )


def _upward_normals(m: _MeshArrays, faces: np.ndarray) -> np.ndarray:
    n = m.normals[faces]
    out: np.ndarray = np.where(n[:, 2:3] < 0, -n, n)
    return out


def _top_faces(m: _MeshArrays, xy: np.ndarray) -> np.ndarray:
    """Index of the highest face above each xy (n, 2) along -Z, -1 where none (retries nudged rays)."""
    mesh = m.mesh
    top = float(m.bounds[1, 2])
    scale = float(np.ptp(m.bounds, axis=0).max()) or 1.0
    direction = np.tile([0.0, 0.0, -1.0], (xy.shape[0], 1))
    origins = np.column_stack([xy, np.full(xy.shape[0], top + 0.1 * scale + 1.0)])
    faces = np.asarray(mesh.ray.intersects_first(origins, direction), dtype=np.int64)
    miss = np.flatnonzero(faces < 0)
    nudge = 1e-7 * scale
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (1, -1), (-1, -1)):
        if not miss.size:
            break
        o = origins[miss] + [dx * nudge, dy * nudge, 0.0]
        found = np.asarray(mesh.ray.intersects_first(o, direction[miss]), dtype=np.int64)
        faces[miss] = found
        miss = miss[found < 0]
    return faces


def _plane_z(m: _MeshArrays, faces: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """z of each face's plane at xy (float64); for vertical faces the face's highest z."""
    v0 = m.vertices[m.faces[faces, 0]]
    n = m.normals[faces]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = v0[:, 2] - (n[:, 0] * (xy[:, 0] - v0[:, 0]) + n[:, 1] * (xy[:, 1] - v0[:, 1])) / n[:, 2]
    vertical = np.abs(n[:, 2]) <= VERTICAL_NZ
    if vertical.any():
        z[vertical] = m.vertices[m.faces[faces[vertical]], 2].max(axis=1)
    out: np.ndarray = z
    return out


def top_surface_z(mesh: trimesh.Trimesh, xy: ArrayLike) -> TopSurface:
    """Upper-surface height at xy (n, 2) mm by vertical rays: z (n,), normals (n, 3), hit (n,)."""
    pts = as_points(xy, "xy", dims=(2,))
    m = _arrays(mesh)
    faces = _top_faces(m, pts)
    hit = faces >= 0
    z = np.full(pts.shape[0], np.nan)
    normals = np.full((pts.shape[0], 3), np.nan)
    if hit.any():
        z[hit] = _plane_z(m, faces[hit], pts[hit])
        normals[hit] = _upward_normals(m, faces[hit])
    return TopSurface(z, normals, hit)


def _off_surface(
    xy: np.ndarray, vertex_hit: np.ndarray, exit_xy: np.ndarray, gap_xy: np.ndarray, gap_segment: int
) -> OffSurfaceError:
    """The error for the first stretch of the trace that is not over the part."""
    off = np.flatnonzero(~vertex_hit[: gap_segment + 1])
    if off.size:
        coord = [round(float(c), 6) for c in xy[off[0]]]
        message = f"trace point {off[0]} at x={coord[0]}, y={coord[1]} is not over the part"
    else:
        coord = [round(float(c), 6) for c in gap_xy]
        leave = [round(float(c), 6) for c in exit_xy]
        message = (
            f"the trace leaves the part's surface at x={leave[0]}, y={leave[1]} (x={coord[0]}, y={coord[1]} "
            f"is not over the part; between trace points {gap_segment} and {gap_segment + 1})"
        )
    return OffSurfaceError(message, field="geometry", value=coord)


def drape_polyline(mesh: trimesh.Trimesh, xy: ArrayLike, tolerance: Tolerance = DEFAULT_TOLERANCE) -> DrapedPath:
    """Drape a top-view polyline xy (n, 2) mm onto the mesh's upper surface, exactly.

    Every crossing with a projected triangle edge is inserted; raises OffSurfaceError
    naming the first coordinate not over the part, DegenerateGeometryError for a
    zero-length polyline.
    """
    pts = as_points(xy, "xy", dims=(2,), min_count=2)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    keep = np.concatenate([[True], seg > tolerance.dedup_mm])
    pts = pts[keep]
    if pts.shape[0] < 2:
        raise DegenerateGeometryError("the trace has zero length", field="geometry", value=pts[0])
    p0, p1 = pts[:-1], pts[1:]
    m = _arrays(mesh)
    s_idx, t = segment_edge_crossings(edge_grid(mesh), p0, p1)
    seg_id = np.concatenate([np.arange(p0.shape[0]), s_idx, [p0.shape[0] - 1]])
    tt = np.concatenate([np.zeros(p0.shape[0]), t, [1.0]])
    order = np.lexsort((tt, seg_id))
    seg_id, tt = seg_id[order], tt[order]
    q = p0[seg_id] + tt[:, None] * (p1 - p0)[seg_id]
    step = np.linalg.norm(np.diff(q, axis=0), axis=1)
    distinct = np.concatenate([[True], step > LENGTH_EPS_MM])
    q, seg_id = q[distinct], seg_id[distinct]
    q[-1] = pts[-1]
    mids = 0.5 * (q[:-1] + q[1:])
    faces = _top_faces(m, mids)
    missed = faces < 0
    if missed.any():
        k = int(np.argmax(missed))
        vertex_hit = _top_faces(m, pts) >= 0
        raise _off_surface(pts, vertex_hit, q[k], mids[k], int(seg_id[k]))
    z_left = _plane_z(m, faces, q[:-1])  # interval k at its start q[k]
    z_right = _plane_z(m, faces, q[1:])  # interval k at its end q[k+1]
    n_face = _upward_normals(m, faces)
    # vertex k (1..K-2) sees interval k-1 (z_right[k-1]) and interval k (z_left[k])
    jump = np.abs(z_right[:-1] - z_left[1:]) > tolerance.dedup_mm
    inner_xy = q[1:-1]
    inner_z = 0.5 * (z_right[:-1] + z_left[1:])
    inner_n = n_face[:-1] + n_face[1:]
    inner_n /= np.linalg.norm(inner_n, axis=1, keepdims=True)
    rows_xy = [q[:1]]
    rows_z = [z_left[:1]]
    rows_n = [n_face[:1]]
    # interleave: for each inner vertex either one point or (left, right) pair at a step
    count = np.where(jump, 2, 1)
    idx = np.repeat(np.arange(inner_xy.shape[0]), count)
    second = np.concatenate([[False], idx[1:] == idx[:-1]])
    z_inner = np.where(jump[idx], np.where(second, z_left[1:][idx], z_right[:-1][idx]), inner_z[idx])
    n_inner = np.where(
        jump[idx, None], np.where(second[:, None], n_face[1:][idx], n_face[:-1][idx]), inner_n[idx]
    )
    rows_xy += [inner_xy[idx], q[-1:]]
    rows_z += [z_inner, z_right[-1:]]
    rows_n += [n_inner, n_face[-1:]]
    points = np.column_stack([np.concatenate(rows_xy), np.concatenate(rows_z)])
    normals = np.concatenate(rows_n)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    xy_len = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    return DrapedPath(points, normals, s, xy_len, float(s[-1]), float(s[-1] / xy_len))


def snap_to_surface(
    mesh: trimesh.Trimesh, points: ArrayLike, max_distance_mm: float, *, field: str = "geometry"
) -> SnappedPoints:
    """Closest mesh points to points (n, 3) mm; OffSurfaceError names the first point farther
    than ``max_distance_mm``.  Normals are the closest facets' normals, oriented upward."""
    pts = as_points(points, "points", dims=(3,))
    m = _arrays(mesh)
    closest, distance, faces = _closest_point(mesh, pts)
    far = distance > max_distance_mm
    if far.any():
        k = int(np.argmax(far))
        coord = [round(float(c), 6) for c in pts[k]]
        raise OffSurfaceError(
            f"point {k} at x={coord[0]}, y={coord[1]}, z={coord[2]} is {distance[k]:.4g} mm from the part's "
            f"surface (max {max_distance_mm} mm)",
            field=field,
            value=coord,
        )
    return SnappedPoints(np.asarray(closest), _upward_normals(m, np.asarray(faces)), np.asarray(distance))
