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
from app.geometry.nurbs import NurbsCurve

__all__ = ["MAX_POINTS", "MAX_RADIUS_MM", "MAX_COORDINATE_MM", "MAX_LENGTH_MM", "MAX_CL_POINTS",
           "check_shape_size", "check_curve_size", "estimated_cl_points"]

MAX_POINTS = 10_000          # polyline points / NURBS control points of one trace
MAX_RADIUS_MM = 1e5          # an arc of 100 m radius is a straight line on any part
MAX_COORDINATE_MM = 1e6      # |x|, |y|, |z| of any given point (1 km)
MAX_LENGTH_MM = 10_000.0     # 10 m of conductor on one part
MAX_CL_POINTS = 100_000      # tool-location points at the chordal tolerance
_SAMPLES_PER_SPAN = 16
_MAX_ESTIMATE_SAMPLES = 50_000


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
