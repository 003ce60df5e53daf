"""Exact curves for imported primitives (2-D, mm): lines, circular arcs, bulge arcs, and
affine moves of any curve (NURBS are affine invariant: moving the control points moves the
curve exactly)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from app.geometry.nurbs import NurbsCurve
from app.geometry.shapes import arc_curve
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = ["line", "polyline", "arc_ccw", "arc_center", "arc_three_points", "bulge_arc", "reversed_curve",
           "transformed", "concatenated", "as_quadratic"]

#: three points are collinear when their determinant is at or below this fraction of their
#: squared scale (at least 1 mm^2)
_EPS = 1e-12
#: a DXF bulge below this is a straight segment
_ZERO_BULGE = 1e-15


def line(p0: npt.ArrayLike, p1: npt.ArrayLike) -> NurbsCurve:
    """Straight segment p0 -> p1 (2,) mm, degree 1 on [0, 1]."""
    return NurbsCurve(1, np.array([0.0, 0.0, 1.0, 1.0]), np.vstack([p0, p1]).astype(float), None)


def polyline(points: npt.ArrayLike) -> NurbsCurve:
    """Degree-1 curve through points (k, 2) mm (consecutive duplicates dropped), chord-length knots."""
    pts = np.asarray(points, float)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > LENGTH_EPS_MM])
    pts = pts[keep]
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    u[-1] = 1.0
    return NurbsCurve(1, np.concatenate([[0.0], u, [1.0]]), pts, None)


def reversed_curve(curve: NurbsCurve) -> NurbsCurve:
    """The same curve traversed the other way (knots mirrored in the domain)."""
    a, b = curve.domain
    knots = (a + b) - curve.knots[::-1]
    return NurbsCurve(curve.degree, knots, curve.control_points[::-1], curve.w[::-1])


def arc_ccw(center: npt.ArrayLike, radius: float, start_rad: float, sweep_rad: float) -> NurbsCurve:
    """Circular arc with a signed sweep (positive CCW, negative CW), |sweep| in (0, 2*pi]."""
    if sweep_rad > 0:
        return arc_curve(np.asarray(center, float), float(radius), float(start_rad), float(sweep_rad))
    end = start_rad + sweep_rad
    return reversed_curve(arc_curve(np.asarray(center, float), float(radius), float(end), float(-sweep_rad)))


def arc_center(start: npt.ArrayLike, end: npt.ArrayLike, center: npt.ArrayLike, clockwise: bool) -> NurbsCurve:
    """Arc from ``start`` to ``end`` around ``center`` (absolute, mm); start == end is a full circle.
    The radius is the start's distance (an inconsistent end is reached by the angle only)."""
    p0, p1, c = (np.asarray(v, float) for v in (start, end, center))
    r = float(np.linalg.norm(p0 - c))
    a0 = float(np.arctan2(*(p0 - c)[::-1]))
    a1 = float(np.arctan2(*(p1 - c)[::-1]))
    ccw = (a1 - a0) % (2 * np.pi)
    if np.linalg.norm(p1 - p0) <= LENGTH_EPS_MM * max(r, 1.0):
        ccw = 2 * np.pi
    sweep = -((2 * np.pi - ccw) if ccw < 2 * np.pi else 2 * np.pi) if clockwise else ccw
    if clockwise and ccw == 2 * np.pi:
        sweep = -2 * np.pi
    return arc_ccw(c, r, a0, sweep)


def arc_three_points(start: npt.ArrayLike, mid: npt.ArrayLike, end: npt.ArrayLike) -> NurbsCurve:
    """The circular arc through start, mid, end (KiCad's form); a straight line if collinear."""
    p1, p2, p3 = (np.asarray(v, float) for v in (start, mid, end))
    d = 2.0 * ((p1[0] - p3[0]) * (p2[1] - p3[1]) - (p2[0] - p3[0]) * (p1[1] - p3[1]))
    if abs(d) <= _EPS * max(1.0, np.abs(np.vstack([p1, p2, p3])).max() ** 2):
        return line(p1, p3)
    a = p1 - p3
    b = p2 - p3
    aa, bb = a @ a, b @ b
    cx = (aa * b[1] - bb * a[1]) / d
    cy = (bb * a[0] - aa * b[0]) / d
    center = p3 + np.array([cx, cy])
    cross = (p2[0] - p1[0]) * (p3[1] - p2[1]) - (p2[1] - p1[1]) * (p3[0] - p2[0])
    return arc_center(p1, p3, center, clockwise=cross < 0)


def bulge_arc(p0: npt.ArrayLike, p1: npt.ArrayLike, bulge: float) -> NurbsCurve:
    """DXF bulge segment p0 -> p1 (2,) mm: bulge = tan(sweep / 4), positive CCW; 0 is a line."""
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    if abs(bulge) < _ZERO_BULGE:
        return line(a, b)
    sweep = 4.0 * float(np.arctan(bulge))
    chord = b - a
    c = float(np.linalg.norm(chord))
    r = c / (2.0 * abs(np.sin(sweep / 2)))
    mid = 0.5 * (a + b)
    normal = np.array([-chord[1], chord[0]]) / c   # left of the chord
    h = r * np.cos(sweep / 2)                      # centre distance from the chord midpoint
    center = mid + np.sign(bulge) * h * normal    # h < 0 for sweeps over 180 degrees: the other side
    a0 = float(np.arctan2(*(a - center)[::-1]))
    return arc_ccw(center, r, a0, sweep)


def transformed(curve: NurbsCurve, matrix: npt.NDArray[np.float64], offset: npt.NDArray[np.float64]) -> NurbsCurve:
    """The curve under x -> matrix @ x + offset (matrix (2, 2), offset (2,)): exact."""
    pts = curve.control_points @ np.asarray(matrix, float).T + np.asarray(offset, float)
    return NurbsCurve(curve.degree, curve.knots, pts, curve.weights)


def as_quadratic(curve: NurbsCurve) -> NurbsCurve:
    """A degree-1 curve raised to degree 2 (same shape: each segment gets its midpoint)."""
    if curve.degree == 2:
        return curve
    pts = curve.control_points
    mids = 0.5 * (pts[:-1] + pts[1:])
    out = np.empty((2 * len(pts) - 1, pts.shape[1]))
    out[0::2], out[1::2] = pts, mids
    inner = np.repeat(curve.knots[2:-2], 2)
    a, b = curve.domain
    return NurbsCurve(2, np.concatenate([[a] * 3, inner, [b] * 3]), out, None)


def concatenated(curves: list[NurbsCurve]) -> NurbsCurve:
    """Join curves (each starting where the previous ends) into one exact curve: degree-1
    pieces are raised to degree 2 when any piece is an arc; knots chain the pieces' spans."""
    if len(curves) == 1:
        return curves[0]
    if any(c.degree != curves[0].degree for c in curves):
        curves = [as_quadratic(c) for c in curves]
    p = curves[0].degree
    knots = [curves[0].knots[: -1].tolist()]
    pts = [curves[0].control_points]
    wts = [curves[0].w]
    offset = curves[0].domain[1]
    for c in curves[1:]:
        a, b = c.domain
        t = c.knots - a + offset
        knots.append(t[p + 1: -1].tolist())
        pts.append(c.control_points[1:])
        wts.append(c.w[1:])
        offset = offset + (b - a)
    allk = np.concatenate([np.asarray(k, float) for k in knots] + [[offset]])
    return NurbsCurve(p, allk, np.vstack(pts), np.concatenate(wts))
