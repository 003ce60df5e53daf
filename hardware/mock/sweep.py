"""Swept-body geometry of the mock probe: where a ball (or a point) moving along a straight
line first touches triangles, a plane, a sphere; where a flat-ended vertical cylinder (a
nozzle) first touches a box or a sphere.

Every function takes the body's start ``origin`` (3,) mm, a unit ``direction`` (3,) and the
move ``length`` mm, and returns a ``Contact`` (distance along the move, contact point,
unit normal pointing from the surface towards the body) or None when nothing is touched
within the move; ``Contact.s < 0`` means the body already overlapped at the start.

The ball-vs-triangles sweep is exact (faces, edges and vertices of a faceted mesh, to
floating point): the first contact is the smallest entry distance over the three kinds
of features, each solved in closed form.  The nozzle sweeps bracket the entry on a fine
sample (``NOZZLE_STEP_MM``) and refine it by bisection to 1e-9 mm.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

NOZZLE_STEP_MM = 0.01
_EPS = 1e-12


class Contact(NamedTuple):
    """First contact of a swept body: distance ``s`` (mm) along the move, the contact
    ``point`` (3,) mm on the surface, the unit ``normal`` (3,) from surface to body."""

    s: float
    point: np.ndarray
    normal: np.ndarray


def _first(candidates: list[Contact]) -> Contact | None:
    return min(candidates, key=lambda c: c.s) if candidates else None


def sweep_ball_triangles(origin: np.ndarray, direction: np.ndarray, length: float,
                         radius: float, tris: np.ndarray, tol: float = 1e-9) -> Contact | None:
    """Ball of ``radius`` (0: a point) swept against triangles ``tris`` (m, 3, 3) mm.

    Faces: the centre reaches distance r from the plane with the touch point inside the
    triangle; edges: the centre line reaches distance r from the edge line with the foot
    on the segment; vertices: the centre reaches distance r from the vertex.  Contacts
    entering before ``-tol`` count only when the ball still overlaps at the start (then
    ``s < 0``: the caller treats it as "started inside")."""
    if len(tris) == 0:
        return None
    p0, d, r = np.asarray(origin, float), np.asarray(direction, float), float(radius)
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    found: list[Contact] = []
    # ---- faces
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    ok = norm > _EPS
    n = n[ok] / norm[ok, None]
    fa, fb, fc = a[ok], b[ok], c[ok]
    dist0 = np.einsum("ij,ij->i", p0 - fa, n)
    side = np.where(dist0 >= 0.0, 1.0, -1.0)
    n = n * side[:, None]
    dist0 = dist0 * side
    v = n @ d
    approaching = v < -_EPS
    if approaching.any():
        n, fa, fb, fc = n[approaching], fa[approaching], fb[approaching], fc[approaching]
        s = (dist0[approaching] - r) / -v[approaching]
        q = p0 + s[:, None] * d - r * n
        # entered before the start: only an overlap NOW counts (the foot of the start on
        # the plane inside the triangle), not where the contact would have been
        q_now = np.where((s < 0.0)[:, None], p0 - dist0[approaching][:, None] * n, q)
        inside = in_triangles(q_now, fa, fb, fc)
        exiting = (dist0[approaching] + r) / -v[approaching]  # the whole ball past the plane
        keep = inside & (s <= length + tol) & (exiting > 0.0)
        if keep.any():
            i = int(np.flatnonzero(keep)[np.argmin(s[keep])])
            found.append(Contact(float(s[i]), q[i], n[i]))
    if r > 0.0:
        found += _edges(p0, d, length, r, tris, tol)
        found += _vertices(p0, d, length, r, np.unique(tris.reshape(-1, 3), axis=0), tol)
    return _first(found)


def in_triangles(q: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                  tol: float = 1e-9) -> np.ndarray:
    """Barycentric inside test of points q (k,3) in their triangles (k,3) x 3 (on plane)."""
    v0, v1, v2 = b - a, c - a, q - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) < _EPS, _EPS, den)
    beta = (d11 * d20 - d01 * d21) / den
    gamma = (d00 * d21 - d01 * d20) / den
    return (beta >= -tol) & (gamma >= -tol) & (beta + gamma <= 1.0 + tol)


def _edges(p0: np.ndarray, d: np.ndarray, length: float, r: float, tris: np.ndarray,
           tol: float) -> list[Contact]:
    starts = np.concatenate([tris[:, 0], tris[:, 1], tris[:, 2]])
    ends = np.concatenate([tris[:, 1], tris[:, 2], tris[:, 0]])
    axis = ends - starts
    span = np.linalg.norm(axis, axis=1)
    ok = span > _EPS
    starts, axis, span = starts[ok], axis[ok] / span[ok, None], span[ok]
    w0 = p0 - starts
    w_perp = w0 - np.einsum("ij,ij->i", w0, axis)[:, None] * axis
    d_perp = d - (axis @ d)[:, None] * axis
    qa = np.einsum("ij,ij->i", d_perp, d_perp)
    qb = np.einsum("ij,ij->i", w_perp, d_perp)
    qc = np.einsum("ij,ij->i", w_perp, w_perp) - r * r
    disc = qb * qb - qa * qc
    ok = (qa > _EPS) & (disc >= 0.0)
    if not ok.any():
        return []
    root = np.sqrt(disc[ok])
    s_in = (-qb[ok] - root) / qa[ok]
    s_out = (-qb[ok] + root) / qa[ok]
    foot = np.einsum("ij,ij->i", w0[ok] + np.maximum(s_in, 0.0)[:, None] * d, axis[ok])
    keep = (s_out > 0.0) & (s_in <= length + tol) & (foot >= 0.0) & (foot <= span[ok])
    if not keep.any():
        return []
    i = int(np.flatnonzero(keep)[np.argmin(s_in[keep])])
    point = starts[ok][i] + foot[i] * axis[ok][i]
    centre = p0 + s_in[i] * d
    return [Contact(float(s_in[i]), point, (centre - point) / r)]


def _vertices(p0: np.ndarray, d: np.ndarray, length: float, r: float, points: np.ndarray,
              tol: float) -> list[Contact]:
    w0 = p0 - points
    half_b = w0 @ d
    disc = half_b * half_b - (np.einsum("ij,ij->i", w0, w0) - r * r)
    ok = disc >= 0.0
    if not ok.any():
        return []
    root = np.sqrt(disc[ok])
    s_in, s_out = -half_b[ok] - root, -half_b[ok] + root
    keep = (s_out > 0.0) & (s_in <= length + tol)
    if not keep.any():
        return []
    i = int(np.flatnonzero(keep)[np.argmin(s_in[keep])])
    point = points[ok][i]
    centre = p0 + s_in[i] * d
    return [Contact(float(s_in[i]), point, (centre - point) / r)]


def sweep_ball_plane(origin: np.ndarray, direction: np.ndarray, length: float, radius: float,
                     z: float) -> Contact | None:
    """Ball swept against the horizontal plane ``z`` (touchable from above)."""
    p0, d = np.asarray(origin, float), np.asarray(direction, float)
    height = p0[2] - z
    if d[2] >= -_EPS:
        return Contact(-1.0, np.array([p0[0], p0[1], z]), np.array([0.0, 0.0, 1.0])) \
            if height < radius - 1e-9 else None
    s = (height - radius) / -d[2]
    if s > length + 1e-9:
        return None
    centre = p0 + s * d
    return Contact(float(s), np.array([centre[0], centre[1], z]), np.array([0.0, 0.0, 1.0]))


def sweep_ball_sphere(origin: np.ndarray, direction: np.ndarray, length: float, radius: float,
                      centre: np.ndarray, sphere_radius: float) -> Contact | None:
    """Ball swept against a sphere: the centre path meets the sphere of radius R + r."""
    p0, d, c = np.asarray(origin, float), np.asarray(direction, float), np.asarray(centre, float)
    big = sphere_radius + radius
    w0 = p0 - c
    half_b = float(w0 @ d)
    disc = half_b * half_b - (float(w0 @ w0) - big * big)
    if disc < 0.0:
        return None
    s_in, s_out = -half_b - math.sqrt(disc), -half_b + math.sqrt(disc)
    if s_out <= 0.0 or s_in > length + 1e-9:
        return None
    ball = p0 + s_in * d
    normal = (ball - c) / big
    return Contact(float(s_in), c + sphere_radius * normal, normal)


# ---------------------------------------------------------------------------- nozzle body
def _entry(inside, origin: np.ndarray, direction: np.ndarray, length: float) -> float | None:
    """Smallest s in [0, length] where ``inside(points (k,3)) -> (k,) bool`` holds
    (sampled every ``NOZZLE_STEP_MM``, refined by bisection); -1 when inside at 0."""
    count = max(int(math.ceil(length / NOZZLE_STEP_MM)) + 1, 2)
    s = np.linspace(0.0, length, count)
    hits = inside(origin + s[:, None] * direction)
    if not hits.any():
        return None
    first = int(np.argmax(hits))
    if first == 0:
        return -1.0
    lo, hi = float(s[first - 1]), float(s[first])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if inside((origin + mid * direction)[None, :])[0]:
            hi = mid
        else:
            lo = mid
        if hi - lo < 1e-10:
            break
    return hi


def sweep_nozzle_box(tip: np.ndarray, direction: np.ndarray, length: float, diameter: float,
                     lo: np.ndarray, hi: np.ndarray) -> float | None:
    """A flat-ended vertical cylinder (tip at the bottom, endless upwards) of ``diameter``
    swept against the box [lo, hi]: entry distance (mm), -1 when touching at the start."""
    half = diameter / 2.0

    def inside(points: np.ndarray) -> np.ndarray:
        dx = np.maximum(np.maximum(lo[0] - points[:, 0], points[:, 0] - hi[0]), 0.0)
        dy = np.maximum(np.maximum(lo[1] - points[:, 1], points[:, 1] - hi[1]), 0.0)
        return (points[:, 2] <= hi[2]) & (dx * dx + dy * dy <= half * half)

    return _entry(inside, np.asarray(tip, float), np.asarray(direction, float), length)


def sweep_nozzle_sphere(tip: np.ndarray, direction: np.ndarray, length: float, diameter: float,
                        centre: np.ndarray, sphere_radius: float) -> float | None:
    """The same cylinder against a sphere: it overlaps when the tip is below the top and
    the horizontal distance is within D/2 + the sphere's radius at the tip's height (at
    the equator when the tip is below it)."""
    half, c, big = diameter / 2.0, np.asarray(centre, float), sphere_radius

    def inside(points: np.ndarray) -> np.ndarray:
        h = np.clip(points[:, 2] - c[2], 0.0, None)
        below_top = points[:, 2] - c[2] < big
        reach = half + np.sqrt(np.clip(big * big - h * h, 0.0, None))
        rho = np.hypot(points[:, 0] - c[0], points[:, 1] - c[1])
        return below_top & (rho <= reach)

    return _entry(inside, np.asarray(tip, float), np.asarray(direction, float), length)
