"""Trace shapes (the API's geometry objects) -> NurbsCurve.

- ``{"type": "line", "start": [x, y(, z)], "end": [...]}`` -> degree 1
- ``{"type": "arc", "center": [x, y], "radius": r, "start_deg": a0, "end_deg": a1}`` ->
  exact rational quadratic, counter-clockwise from a0 to a1 (a1 = a0 + 360 is a full
  circle), split into pieces of at most 90 degrees
- ``{"type": "polyline", "points": [[x, y(, z)], ...]}`` -> degree 1, chord-length knots
- ``{"type": "nurbs", "degree", "control_points", "weights"?, "knots"?}``
Coordinates in mm, angles in degrees at this boundary (radians inside).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from app.geometry.errors import DegenerateGeometryError, GeometryError
from app.geometry.nurbs import NurbsCurve
from app.geometry.shapes_limits import check_curve_size, check_shape_size
from app.geometry.tolerance import DEFAULT_TOLERANCE, ROUNDOFF_SLACK, Tolerance
from app.geometry.validation import as_points, check_distinct_consecutive

__all__ = ["trace_curve", "line_curve", "arc_curve", "polyline_curve", "SHAPE_TYPES"]

SHAPE_TYPES = ("line", "arc", "polyline", "nurbs")


def _require(geometry: Mapping[str, Any], key: str, field: str) -> Any:
    if key not in geometry:
        raise GeometryError(f"{field}.{key} is required", field=f"{field}.{key}", value=None)
    return geometry[key]


def _number(value: Any, field: str) -> float:
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating))
            or not np.isfinite(value)):
        raise GeometryError(f"{field} must be a finite number", field=field, value=value)
    return float(value)


def line_curve(start: np.ndarray, end: np.ndarray, *, tolerance: Tolerance = DEFAULT_TOLERANCE,
               field: str = "geometry") -> NurbsCurve:
    """Straight segment start -> end (d,) mm as a degree-1 curve on [0, 1]."""
    if start.shape != end.shape:
        raise GeometryError(f"{field}.end must have as many coordinates as start", field=f"{field}.end",
                            value=end)
    if np.linalg.norm(end - start) <= tolerance.dedup_mm:
        raise DegenerateGeometryError(f"{field}: zero-length line", field=f"{field}.end", value=end)
    return NurbsCurve(1, np.array([0.0, 0.0, 1.0, 1.0]), np.vstack([start, end]), None)


def arc_curve(center: np.ndarray, radius: float, start_rad: float, sweep_rad: float) -> NurbsCurve:
    """Exact circular arc (NURBS Book A7.1): CCW from ``start_rad`` by ``sweep_rad`` in (0, 2*pi].

    center (2,) mm, radius mm -> rational quadratic, pieces of <= 90 deg with middle weights
    cos(half piece angle), domain [0, 1] with one knot pair per piece boundary.
    """
    pieces = max(1, int(np.ceil(sweep_rad / (np.pi / 2) - ROUNDOFF_SLACK)))
    dtheta = sweep_rad / pieces
    angles = start_rad + dtheta * np.arange(pieces + 1)
    ends = center + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    mids_angle = angles[:-1] + dtheta / 2
    mids = center + (radius / np.cos(dtheta / 2)) * np.column_stack([np.cos(mids_angle), np.sin(mids_angle)])
    points = np.empty((2 * pieces + 1, 2))
    points[0::2], points[1::2] = ends, mids
    weights = np.ones(2 * pieces + 1)
    weights[1::2] = np.cos(dtheta / 2)
    inner = np.repeat(np.arange(1, pieces) / pieces, 2)
    knots = np.concatenate([[0.0, 0.0, 0.0], inner, [1.0, 1.0, 1.0]])
    return NurbsCurve(2, knots, points, weights)


def polyline_curve(points: np.ndarray, *, tolerance: Tolerance = DEFAULT_TOLERANCE,
                   field: str = "geometry.points") -> NurbsCurve:
    """Degree-1 curve through points (k, d), knots at normalised chord length (u ~ arc length)."""
    seg = check_distinct_consecutive(points, tolerance.dedup_mm, field)
    u = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    u[-1] = 1.0
    return NurbsCurve(1, np.concatenate([[0.0], u, [1.0]]), points, None)


def _arc(geometry: Mapping[str, Any], field: str, tolerance: Tolerance) -> NurbsCurve:
    center = as_points([_require(geometry, "center", field)], f"{field}.center", dims=(2,))[0]
    radius = _number(_require(geometry, "radius", field), f"{field}.radius")
    if radius <= tolerance.dedup_mm:
        raise DegenerateGeometryError(f"{field}.radius must be positive", field=f"{field}.radius", value=radius)
    a0 = _number(_require(geometry, "start_deg", field), f"{field}.start_deg")
    a1 = _number(_require(geometry, "end_deg", field), f"{field}.end_deg")
    sweep = (a1 - a0) % 360.0
    if sweep == 0.0:
        if a1 == a0:
            raise DegenerateGeometryError(f"{field}: zero-length arc (start_deg == end_deg)",
                                          field=f"{field}.end_deg", value=a1)
        sweep = 360.0
    if radius * np.radians(sweep) <= tolerance.dedup_mm:
        raise DegenerateGeometryError(f"{field}: zero-length arc", field=f"{field}.end_deg", value=a1)
    return arc_curve(center, radius, np.radians(a0), np.radians(sweep))


def trace_curve(geometry: Mapping[str, Any], *, field: str = "geometry",
                tolerance: Tolerance = DEFAULT_TOLERANCE, check_size: bool = True) -> NurbsCurve:
    """The API's geometry dict -> NurbsCurve (2-D or 3-D control points).

    Raises GeometryError subclasses naming the field (e.g. ``geometry.knots``) and value.
    Degenerate (zero-length) traces raise DegenerateGeometryError; traces beyond the size
    limits of :mod:`app.geometry.shapes_limits` (points, radius, length, sampling) a GeometryError.
    ``check_size=False`` leaves the built curve's length and sampling checks to the caller
    (:func:`~app.geometry.shapes_limits.curves_clearly_within_limits` of many curves at once).
    """
    if not isinstance(geometry, Mapping):
        raise GeometryError(f"{field} must be an object", field=field, value=str(type(geometry).__name__))
    kind = _require(geometry, "type", field)
    check_shape_size(geometry, field)  # counts and radius before any array is built
    if kind == "line":
        start = as_points([_require(geometry, "start", field)], f"{field}.start")[0]
        end = as_points([_require(geometry, "end", field)], f"{field}.end")[0]
        curve = line_curve(start, end, tolerance=tolerance, field=field)
    elif kind == "arc":
        curve = _arc(geometry, field, tolerance)
    elif kind == "polyline":
        pts = as_points(_require(geometry, "points", field), f"{field}.points", min_count=2)
        curve = polyline_curve(pts, tolerance=tolerance, field=f"{field}.points")
    elif kind == "nurbs":
        curve = NurbsCurve.from_dict(geometry, field=field)
    else:
        raise GeometryError(f"{field}.type must be one of {', '.join(SHAPE_TYPES)}", field=f"{field}.type",
                            value=kind)
    if not check_size:
        return curve
    check_curve_size(curve, tolerance.chord_mm, field)  # length and sampling work bounded
    if curve.length <= tolerance.dedup_mm:
        raise DegenerateGeometryError(f"{field}: the trace has zero length", field=field, value=curve.length)
    return curve
