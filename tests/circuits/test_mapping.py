"""`wrap` on a cylinder against its analytic unrolling; on a doubly curved part the stretch
is reported and bounded; `project` keeps the exact placed curve."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.circuits.curves import arc_ccw, line
from app.circuits.layout import Layout, LayoutTrace, Source
from app.circuits.mapping import MappingOptions, _layout_samples, map_layout
from app.circuits.placement import LayoutPlacement

R = 40.0


def _sheet(height, half_x: float = 36.0, half_y: float = 40.0, n: int = 600, m: int = 40) -> trimesh.Trimesh:
    """A triangulated height field z = height(x, y) over a rectangle (vertices on the surface)."""
    x = np.linspace(-half_x, half_x, n + 1)
    y = np.linspace(-half_y, half_y, m + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), height(X.ravel(), Y.ravel())])
    idx = np.arange(len(V)).reshape(n + 1, m + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return trimesh.Trimesh(V, np.vstack([np.column_stack([a, b, d]), np.column_stack([b, c, d])]), process=False)


def _cylinder() -> trimesh.Trimesh:
    """The top of a cylinder of radius R along y, vertices exactly on it (360 facets over 0.9 pi:
    0.3 um from the true cylinder)."""
    th = np.linspace(-0.45 * np.pi, 0.45 * np.pi, 361)
    y = np.linspace(-40, 40, 21)
    T, Y = np.meshgrid(th, y, indexing="ij")
    V = np.column_stack([R * np.sin(T).ravel(), Y.ravel(), R * np.cos(T).ravel()])
    idx = np.arange(len(V)).reshape(len(th), len(y))
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return trimesh.Trimesh(V, np.vstack([np.column_stack([a, d, b]), np.column_stack([b, d, c])]), process=False)


def _layout() -> Layout:
    src = Source("t", "L", "", 0.2)
    return Layout("t", "test", "mm", traces=[
        LayoutTrace(line([0, 0], [30, 0]), Source("t", "L", "a", 0.2)),
        LayoutTrace(line([-10, -5], [20, 15]), Source("t", "L", "b", 0.2)),
        LayoutTrace(arc_ccw([5, 5], 8, 0.0, 3.0), Source("t", "L", "c", 0.3)),
        LayoutTrace(line([-25, 10], [-5, 10]), src)])


def test_wrap_on_a_cylinder_matches_the_analytic_unrolling():
    layout = _layout()
    mapped = map_layout(layout, LayoutPlacement((0.0, 0.0)), _cylinder(), MappingOptions("wrap"))
    for trace, source in zip(mapped.traces, layout.traces):
        assert trace.on_part
        # each mapped point comes from a layout point (u, v), which lies at (R sin(u/R), v, R cos(u/R))
        samples = _layout_samples(source, MappingOptions("wrap"))
        exact = np.column_stack([R * np.sin(samples[:, 0] / R), samples[:, 1], R * np.cos(samples[:, 0] / R)])
        assert len(samples) == len(trace.surface_points) > 50
        assert np.linalg.norm(trace.surface_points - exact, axis=1).max() <= 0.005
        assert abs(trace.stretch - 1.0) <= 1e-3
        assert trace.length_mm == pytest.approx(source.curve.length, rel=1e-3)
    # the exact positions of the two ends of the first trace
    first = mapped.traces[0].surface_points
    np.testing.assert_allclose(first[0], [0, 0, R], atol=0.005)
    np.testing.assert_allclose(first[-1], [R * np.sin(30 / R), 0, R * np.cos(30 / R)], atol=0.005)


def test_wrap_on_a_sphere_cap_reports_a_bounded_stretch():
    rs = 60.0
    mesh = _sheet(lambda x, y: np.sqrt(rs**2 - x**2 - y**2), half_x=30, half_y=30, n=120, m=120)
    layout = Layout("t", "test", "mm", traces=[LayoutTrace(line([-20, 15], [20, 15]), Source("t", "L", "", 0.2))])
    mapped = map_layout(layout, LayoutPlacement((0.0, 0.0)), mesh, MappingOptions("wrap", max_stretch=1.001))
    (trace,) = mapped.traces
    # radial geodesics keep length; a chord 15 mm off the anchor is shortened on a sphere
    # (exp map: geodesic circles of radius r have circumference 2 pi Rs sin(r / Rs) < 2 pi r)
    assert 0.97 < trace.stretch < 1.0
    assert any(w["kind"] == "stretch" for w in mapped.warnings)


def test_project_keeps_the_exact_curve_and_reports_the_slope_stretch():
    mesh = _sheet(lambda x, y: 0.1 * x, n=40, m=40)          # a plane of slope 0.1 in x
    layout = Layout("t", "test", "mm", traces=[LayoutTrace(line([0, 0], [10, 0]), Source("t", "L", "", 0.2))])
    mapped = map_layout(layout, LayoutPlacement((1.0, 2.0), rotation_deg=0.0), mesh, MappingOptions("project"))
    (trace,) = mapped.traces
    assert trace.geometry["type"] == "nurbs"
    np.testing.assert_allclose(trace.geometry["control_points"], [[1, 2], [11, 2]], atol=1e-12)
    assert trace.stretch == pytest.approx(np.sqrt(1.01), abs=1e-9)


def test_placement_rotates_mirrors_and_warns_about_close_traces_and_leaving():
    mesh = _sheet(lambda x, y: 0 * x, half_x=20, half_y=20, n=20, m=20)
    src = Source("t", "L", "", 0.4)
    layout = Layout("t", "test", "mm", traces=[
        LayoutTrace(line([0, 0], [10, 0]), src), LayoutTrace(line([1, 0.3], [9, 0.3]), src),
        LayoutTrace(line([0, 5], [40, 5]), src)])
    mapped = map_layout(layout, LayoutPlacement((0.0, 0.0), rotation_deg=90.0, mirror=True), mesh)
    # mirror x then rotate 90: (10, 0) -> (-10, 0) -> (0, -10)
    np.testing.assert_allclose(np.asarray(mapped.traces[0].geometry["control_points"])[1], [0, -10], atol=1e-12)
    kinds = sorted(w["kind"] for w in mapped.warnings)
    assert "spacing" in kinds and "leaves_part" in kinds
