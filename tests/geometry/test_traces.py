"""build_nominal_trace: the service's entry point for a trace on a part."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.drape import top_surface_z
from app.geometry.errors import GeometryError, OffSurfaceError
from app.geometry.shapes import trace_curve
from app.geometry.tolerance import Tolerance
from app.geometry.traces import build_nominal_trace
from tests.geometry.conftest import height_field_mesh


def test_arc_on_a_tilted_plane_has_the_analytic_length() -> None:
    a = 0.2
    mesh = height_field_mesh(lambda x, y: a * x + 4.0, 5, 5)
    geometry = {"type": "arc", "center": [20, 30], "radius": 10, "start_deg": 0, "end_deg": 360}
    tol = Tolerance(chord_mm=1e-4)
    trace = build_nominal_trace(mesh, geometry, "xy", tol)
    # the circle lifted onto z = a x + c is an ellipse; its length by dense quadrature
    t = np.linspace(0, 2 * np.pi, 200001)
    speed = 10 * np.sqrt(1 + (a * np.sin(t)) ** 2)
    exact = np.trapezoid(speed, t)
    assert trace.length_mm == pytest.approx(exact, rel=2e-5)
    assert trace.z_range == pytest.approx((a * 10 + 4, a * 30 + 4), abs=1e-6)
    assert trace.slope_stretch == pytest.approx(exact / (2 * np.pi * 10), rel=2e-5)
    assert np.allclose(trace.points[0], trace.points[-1])


def test_xy_trace_points_are_on_the_surface() -> None:
    mesh = height_field_mesh(lambda x, y: 5 + np.sin(x / 5) * np.cos(y / 9), 41, 61)
    g = {"type": "nurbs", "degree": 3, "control_points": [[10, 6], [15, 15], [5, 25], [12, 38]]}
    trace = build_nominal_trace(mesh, g, "xy", Tolerance())
    top = top_surface_z(mesh, trace.points[:, :2])
    assert np.abs(top.z - trace.points[:, 2]).max() < 1e-9
    # top view stays within the chord tolerance of the design curve
    assert (trace_curve(g, tolerance=Tolerance()).invert(trace.points[:, :2]).distance.max()
            <= Tolerance().chord_mm + 1e-12)


def test_3d_trace_is_snapped_and_off_surface_points_are_named() -> None:
    mesh = height_field_mesh(lambda x, y: 0.1 * y + 2, 5, 5)
    pts = [[5, 5, 2.5], [5, 20, 4.0], [10, 40, 6.0]]
    trace = build_nominal_trace(mesh, {"type": "polyline", "points": pts}, "3d", Tolerance())
    assert np.allclose(trace.points, pts, atol=1e-9)
    with pytest.raises(OffSurfaceError) as info:
        build_nominal_trace(mesh, {"type": "polyline", "points": [[5, 5, 2.5], [5, 20, 5.0]]}, "3d", Tolerance())
    assert "z=" in info.value.message


def test_frame_and_dimension_errors() -> None:
    mesh = trimesh.creation.box(extents=[10, 10, 2])
    line3 = {"type": "line", "start": [0, 0, 1], "end": [1, 1, 1]}
    line2 = {"type": "line", "start": [0, 0], "end": [1, 1]}
    with pytest.raises(GeometryError) as info:
        build_nominal_trace(mesh, line3, "xy")
    assert info.value.field == "geometry"
    with pytest.raises(GeometryError):
        build_nominal_trace(mesh, line2, "3d")
    with pytest.raises(GeometryError) as info:
        build_nominal_trace(mesh, line2, "uv")  # type: ignore[arg-type]
    assert info.value.field == "frame"
    with pytest.raises(OffSurfaceError):
        build_nominal_trace(mesh, {"type": "line", "start": [0, 0], "end": [9, 0]}, "xy")


def test_tolerance_is_validated() -> None:
    with pytest.raises(GeometryError) as info:
        Tolerance(chord_mm=0.0)
    assert info.value.field == "chord_mm" and info.value.value == 0.0
    with pytest.raises(GeometryError):
        Tolerance(snap_mm=float("nan"))
