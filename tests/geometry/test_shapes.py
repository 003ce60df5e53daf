"""Trace shapes -> NURBS: exact arcs, lines, polylines, user NURBS, and typed bad-input errors."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.errors import DegenerateGeometryError, GeometryError, KnotVectorError, WeightError
from app.geometry.shapes import trace_curve


@pytest.mark.parametrize("a0,a1,sweep", [(0, 90, 90), (10, 200, 190), (350, 10, 20), (0, 360, 360),
                                         (30, -60, 270), (-45, 300.5, 345.5), (0, 1e-3, 1e-3)])
def test_arc_is_exact(a0: float, a1: float, sweep: float) -> None:
    r, centre = 40.0, np.array([3.0, -2.0])
    c = trace_curve({"type": "arc", "center": centre.tolist(), "radius": r, "start_deg": a0, "end_deg": a1})
    u = np.linspace(0, 1, 2001)
    p = c.evaluate(u)
    assert np.abs(np.linalg.norm(p - centre, axis=1) - r).max() < 1e-12 * r
    # a 0.001 deg arc's second derivative is a difference of nearly equal coordinates
    assert np.allclose(c.curvature(u), 1 / r, rtol=1e-9 if sweep >= 1 else 1e-5)
    assert c.length == pytest.approx(r * np.radians(sweep), rel=1e-11)
    ang = np.degrees(np.arctan2(*(p[[0, -1]] - centre).T[::-1]))
    assert np.allclose((ang - [a0, a1] + 180) % 360 - 180, 0, atol=1e-9)
    # counter-clockwise: the polar angle increases monotonically along the curve
    unwrapped = np.unwrap(np.arctan2(p[:, 1] - centre[1], p[:, 0] - centre[0]))
    assert np.all(np.diff(unwrapped) > 0)
    assert np.allclose(c.weights[1::2], np.cos(np.radians(sweep) / (2 * ((c.weights.size - 1) // 2))))
    assert (c.weights.size - 1) // 2 == max(1, int(np.ceil(sweep / 90 - 1e-12)))  # pieces of <= 90 deg
    assert c.to_dict()["degree"] == 2


def test_line_and_polyline() -> None:
    line = trace_curve({"type": "line", "start": [1, 2], "end": [4, 6]})
    assert line.degree == 1 and line.length == pytest.approx(5.0)
    poly = trace_curve({"type": "polyline", "points": [[0, 0, 1], [3, 4, 1], [3, 4, 6]]})
    assert poly.length == pytest.approx(10.0)
    assert np.allclose(poly.evaluate([0.5]), [[3, 4, 1]])  # chord-length knots: u ~ arc length


def test_nurbs_shape_with_defaults_and_given_knots() -> None:
    g = {"type": "nurbs", "degree": 3, "control_points": [[0, 0], [10, 5], [20, -5], [30, 0], [40, 2]]}
    c = trace_curve(g)
    assert c.knots.tolist() == [0, 0, 0, 0, 0.5, 1, 1, 1, 1] and np.allclose(c.weights, 1)
    c2 = trace_curve({**g, "knots": [0, 0, 0, 0, 0.3, 1, 1, 1, 1], "weights": [1, 2, 1, 1, 1]})
    assert np.allclose(c2.evaluate([0, 1]), [[0, 0], [40, 2]])


@pytest.mark.parametrize(
    "geometry,error,field,value",
    [
        ({"type": "spiral"}, GeometryError, "geometry.type", "spiral"),
        ({"type": "line", "start": [1, 2]}, GeometryError, "geometry.end", None),
        ({"type": "line", "start": [1, 2], "end": [1, 2]}, DegenerateGeometryError, "geometry.end", [1.0, 2.0]),
        ({"type": "line", "start": [1, 2], "end": [1, float("nan")]}, DegenerateGeometryError, "geometry.end[0]",
         [1.0, "nan"]),
        ({"type": "arc", "center": [0, 0], "radius": 0, "start_deg": 0, "end_deg": 90}, DegenerateGeometryError,
         "geometry.radius", 0.0),
        ({"type": "arc", "center": [0, 0], "radius": 5, "start_deg": 30, "end_deg": 30}, DegenerateGeometryError,
         "geometry.end_deg", 30.0),
        ({"type": "arc", "center": [0, 0], "radius": "big", "start_deg": 0, "end_deg": 9}, GeometryError,
         "geometry.radius", "big"),
        ({"type": "polyline", "points": [[0, 0]]}, DegenerateGeometryError, "geometry.points", 1),
        ({"type": "polyline", "points": [[0, 0], [1, 1], [1, 1]]}, DegenerateGeometryError, "geometry.points[2]",
         [1.0, 1.0]),
        ({"type": "nurbs", "degree": 2, "control_points": [[0, 0], [1, 1], [2, 0]], "knots": [0, 0, 0, 1, 1]},
         KnotVectorError, "geometry.knots", 5),
        ({"type": "nurbs", "degree": 2, "control_points": [[0, 0], [1, 1], [2, 0]], "weights": [1, -1, 1]},
         WeightError, "geometry.weights", -1.0),
        ({"type": "nurbs", "degree": 3, "control_points": [[0, 0], [1, 1], [2, 0]]}, DegenerateGeometryError,
         "geometry.control_points", 3),
        ({"type": "nurbs", "degree": 1, "control_points": [[2, 2], [2, 2]]}, DegenerateGeometryError, "geometry",
         0.0),
    ],
)
def test_bad_shapes_raise_typed_errors(geometry: dict, error: type, field: str, value: object) -> None:
    with pytest.raises(error) as info:
        trace_curve(geometry)
    assert info.value.field == field
    assert info.value.value == value
