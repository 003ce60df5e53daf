"""Size limits of trace shapes, checked before any sampling or draping work.

A trace is created in a request thread: its cost must be bounded by its input.  The work
grows with the number of points given (polyline points, NURBS control points), with the
curve's length (draping inserts every triangle-edge crossing) and with the number of
tool-location points the chordal tolerance needs, about
``integral sqrt(kappa / (8 chord_mm)) ds`` (a circle of radius R: 2 pi sqrt(R / (8 chord_mm)),
2.2 million points for R = 1e9 mm).  Each limit is a 422 naming the field and the value.
Units: mm.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from app.geometry.errors import GeometryError
from app.geometry.nurbs import GAUSS_W, GAUSS_X, PIECES_PER_SPAN, NurbsCurve
from app.geometry.nurbs_batch import CurveBatch

__all__ = ["MAX_POINTS", "MAX_RADIUS_MM", "MAX_COORDINATE_MM", "MAX_LENGTH_MM", "MAX_CL_POINTS",
           "check_shape_size", "check_curve_size", "curves_clearly_within_limits", "estimated_cl_points"]

MAX_POINTS = 10_000          # polyline points / NURBS control points of one trace
MAX_RADIUS_MM = 1e5          # an arc of 100 m radius is a straight line on any part
MAX_COORDINATE_MM = 1e6      # |x|, |y|, |z| of any given point (1 km)
MAX_LENGTH_MM = 10_000.0     # 10 m of conductor on one part
MAX_CL_POINTS = 100_000      # tool-location points at the chordal tolerance
_SAMPLES_PER_SPAN = 16
_MAX_ESTIMATE_SAMPLES = 50_000
_CLEAR_REL = 1e-6  # a batch's figure this close to a limit is checked curve by curve


def _count(value: Any) -> int:
    return len(value) if isinstance(value, (list, tuple)) else 0


def check_shape_size(geometry: Mapping[str, Any], field: str) -> None:
    """Counts and magnitudes of the raw geometry dict (before any array is built)."""
    for key in ("points", "control_points"):
        n = _count(geometry.get(key))
        if n > MAX_POINTS:
            raise GeometryError(f"{field}.{key}: {n} points; a trace takes at most {MAX_POINTS}",
                                field=f"{field}.{key}", value=n)
    radius = geometry.get("radius")
    if isinstance(radius, (int, float)) and not isinstance(radius, bool) and abs(radius) > MAX_RADIUS_MM:
        raise GeometryError(f"{field}.radius: {radius:g} mm; an arc's radius is at most {MAX_RADIUS_MM:g} mm "
                            "(a larger one is a line at any part's scale)", field=f"{field}.radius", value=radius)


def check_coordinates(points: np.ndarray, field: str) -> None:
    """|coordinates| of points (k, d) within MAX_COORDINATE_MM."""
    if points.size and float(np.abs(points).max()) > MAX_COORDINATE_MM:
        worst = int(np.abs(points).max(axis=1).argmax())
        raise GeometryError(f"{field}.{worst}: coordinates beyond +-{MAX_COORDINATE_MM:g} mm",
                            field=f"{field}.{worst}", value=points[worst].tolist())


def estimated_cl_points(curve: NurbsCurve, chord_mm: float) -> float:
    """Tool-location points the chordal tolerance needs: the integral of sqrt(kappa/(8 delta))
    over arc length (trapezoid on at most 50,000 samples; 0 for a degree-1 curve), plus one
    point per knot span."""
    spans = max(1, len(np.unique(curve.knots)) - 1)
    if curve.degree == 1:                      # straight pieces: no curvature, the breakpoints only
        return float(spans + 1)
    a, b = curve.domain
    u = np.linspace(a, b, min(_MAX_ESTIMATE_SAMPLES, _SAMPLES_PER_SPAN * spans + 1))
    d = curve.derivatives(u, 2)
    density = np.sqrt(np.maximum(curve.curvature(u, d), 0.0) / (8.0 * chord_mm)) * np.linalg.norm(d[1], axis=1)
    return float(np.sum(0.5 * (density[1:] + density[:-1]) * np.diff(u))) + spans + 1


def check_curve_size(curve: NurbsCurve, chord_mm: float, field: str) -> None:
    """The built curve: length and tool-location points within the limits."""
    check_coordinates(np.asarray(curve.control_points, dtype=float), f"{field}.control_points")
    if curve.length > MAX_LENGTH_MM:
        raise GeometryError(f"{field}: the trace is {curve.length:.6g} mm long; at most {MAX_LENGTH_MM:g} mm",
                            field=field, value=curve.length)
    needed = estimated_cl_points(curve, chord_mm)
    if needed > MAX_CL_POINTS:
        raise GeometryError(f"{field}: about {needed:,.0f} points are needed to follow this curve within "
                            f"{chord_mm:g} mm; at most {MAX_CL_POINTS:,} (the curve is too long or too tightly "
                            "curved)", field=field, value=round(needed))


def curves_clearly_within_limits(curves: list[NurbsCurve], chord_mm: float, min_length_mm: float) -> bool:
    """:func:`check_curve_size` of every curve, and each longer than ``min_length_mm``, all
    at once: True when every curve passes with a margin (``_CLEAR_REL`` of each figure: the
    batch's figures equal each curve's own to round-off); False when any curve fails or
    comes that close, to be checked one by one (which names the error).

    Lengths: degree 1 exactly (its control polygon), else Gauss-Legendre on quarters of
    each knot span (as :attr:`NurbsCurve.length`); points needed as :func:`estimated_cl_points`.
    """
    if not curves:
        return True
    for dimension in {c.dimension for c in curves}:
        points = np.concatenate([c.control_points for c in curves if c.dimension == dimension])
        if float(np.abs(points).max(initial=0.0)) > MAX_COORDINATE_MM:
            return False
    length = np.empty(len(curves))
    needed = np.empty(len(curves))
    curved: dict[int, list[int]] = {}
    for i, curve in enumerate(curves):
        spans = max(1, int(np.count_nonzero(np.diff(curve.knots) > 0)))
        if curve.degree == 1:
            length[i] = np.sqrt(np.square(np.diff(curve.control_points, axis=0)).sum(axis=1)).sum()
            needed[i] = spans + 1
        else:
            curved.setdefault(curve.dimension, []).append(i)
    for members in curved.values():
        length[members], needed[members] = _lengths_and_needs([curves[i] for i in members], chord_mm)
    return bool((length < MAX_LENGTH_MM * (1 - _CLEAR_REL)).all() and (needed < MAX_CL_POINTS * (1 - _CLEAR_REL)).all()
                and (length > min_length_mm * (1 + _CLEAR_REL)).all())


def _lengths_and_needs(curves: list[NurbsCurve], chord_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Arc length (n,) mm and :func:`estimated_cl_points` (n,) of curves of degree >= 2 and
    one dimension, every curve's samples evaluated at once."""
    batch = CurveBatch(curves)
    # lengths: Gauss-Legendre nodes on PIECES_PER_SPAN pieces of every knot span in the domain
    t = np.arange(PIECES_PER_SPAN) / PIECES_PER_SPAN
    edges = []
    for c in curves:
        br = np.unique(c.knots[(c.knots >= c.domain[0]) & (c.knots <= c.domain[1])])
        edges.append(np.append((br[:-1, None] + np.diff(br)[:, None] * t[None, :]).ravel(), br[-1]))
    pieces = np.array([e.size - 1 for e in edges])
    lo, hi = np.concatenate([e[:-1] for e in edges]), np.concatenate([e[1:] for e in edges])
    half = 0.5 * (hi - lo)
    nodes = (0.5 * (hi + lo))[:, None] + half[:, None] * GAUSS_X[None, :]
    owner = np.repeat(np.repeat(np.arange(len(curves)), pieces), GAUSS_X.size)
    d1 = batch.derivatives(owner, nodes.ravel(), 1)[1]
    speed = np.sqrt(np.square(d1).sum(axis=1)).reshape(nodes.shape)
    length = np.add.reduceat(half * (speed @ GAUSS_W), np.concatenate([[0], np.cumsum(pieces)[:-1]]))
    # points needed: the trapezoid of sqrt(kappa / (8 chord)) |C'| on 16 samples per knot span
    spans = np.array([max(1, np.unique(c.knots).size - 1) for c in curves])
    count = np.minimum(_MAX_ESTIMATE_SAMPLES, _SAMPLES_PER_SPAN * spans + 1)
    u = np.concatenate([np.linspace(c.domain[0], c.domain[1], k) for c, k in zip(curves, count)])
    d = batch.derivatives(np.repeat(np.arange(len(curves)), count), u, 2)
    density = np.sqrt(np.maximum(batch.curvature(d), 0.0) / (8.0 * chord_mm)) * np.sqrt(np.square(d[1]).sum(axis=1))
    area = 0.5 * (density[1:] + density[:-1]) * np.diff(u)
    starts = np.concatenate([[0], np.cumsum(count)[:-1]])
    area[starts[1:] - 1] = 0.0  # the step from one curve's last sample to the next curve's first
    return length, np.add.reduceat(area, starts) + spans + 1
