"""End-to-end checks of plan_five_axis, verified from the program TEXT alone."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.compensation.five_axis import (
    AxisLimitError,
    DegenerateTraceError,
    FiveAxisError,
    FiveAxisParams,
    TraceOffSurfaceError,
    plan_five_axis,
)
from app.compensation.five_axis.kinematics import machine_to_workpiece, rotation_matrices
from app.compensation.five_axis.trace import trace_over_xy
from app.geometry.nurbs_surface import NurbsSurface

H = 0.5
PIVOT = (5.0, -3.0, -20.0)
_WORD = re.compile(r"([XYZACF])(-?\d+(?:\.\d+)?)")


def _parse_g1(text: str) -> np.ndarray:
    """(k, 6) X Y Z A C F of every G1 line (the approach line first)."""
    rows = []
    for line in text.splitlines():
        if line.startswith("G1 "):
            words = dict(_WORD.findall(line))
            rows.append([float(words.get(k, "nan")) for k in "XYZACF"])
    return np.array(rows)


def _ellipse_xy(cx: float, cy: float, ax: float, by: float, n: int = 40) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n)
    return np.column_stack([cx + ax * np.cos(t), cy + by * np.sin(t)])


def _check_program(surface: NurbsSurface, text: str, h: float, pivot: tuple) -> np.ndarray:
    rows = _parse_g1(text)
    xyz, a, c = rows[:, :3], np.radians(rows[:, 3]), np.radians(rows[:, 4])
    tips_wp = machine_to_workpiece(xyz, a, c, np.array(pivot))
    inv = surface.invert(tips_wp)
    # the nozzle is h +- 1 um from the surface
    assert np.abs(inv.distance - h).max() < 1e-3
    n = surface.normal(inv.u, inv.v)
    n *= np.sign(n[:, 2:3])
    turned = np.einsum("kij,kj->ki", rotation_matrices(a, c), n)
    angle = np.degrees(np.arccos(np.clip(turned[:, 2], -1, 1)))
    assert angle.max() < 0.05
    # and straight above the contact point in machine coordinates
    contact_m = np.einsum("kij,kj->ki", rotation_matrices(a, c), inv.closest - pivot) + pivot
    np.testing.assert_allclose(xyz[:, :2], contact_m[:, :2], atol=1e-3)
    np.testing.assert_allclose(xyz[:, 2] - contact_m[:, 2], h, atol=1e-3)
    return rows


def test_program_brings_normal_to_z_at_standoff(sphere: NurbsSurface) -> None:
    trace = trace_over_xy(sphere, _ellipse_xy(4.0, 2.0, 14.0, 9.0))
    params = FiveAxisParams(standoff_mm=H, feed_mm_min=1200, servo_period_s=0.002,
                            segment_mm=1.0, pivot_mm=PIVOT)
    path = plan_five_axis(sphere, trace, params)
    rows = _check_program(sphere, path.program, H, PIVOT)
    assert rows.shape[0] == path.u.size
    assert np.abs(np.diff(rows[:, 4])).max() <= 180.0
    assert path.max_normal_error_deg < 0.05 and path.max_standoff_error_mm < 1e-3
    # inverse-time feed: F = 1 / minutes of each segment, segments at the set feed
    f = rows[1:, 5]
    seg_len = np.array([trace.arc_length(u0, u1) for u0, u1 in zip(path.u[:-1], path.u[1:])])
    minutes = seg_len / params.feed_mm_min
    np.testing.assert_allclose(1.0 / f, minutes, rtol=2e-3)
    assert "G93" in path.program
    # second-order interpolator: < 0.1 % and clearly better than first order
    assert path.feed.max_rel < 1e-3
    assert path.feed.max_rel < 0.2 * path.feed_first_order.max_rel
    # the nominal program is 3-axis, h above the contact points, but tilted from the normal
    nominal = _parse_g1(path.nominal_program)
    assert np.isnan(nominal[:, 3]).all()
    assert path.nominal_max_normal_error_deg > 10.0
    assert path.nominal_max_standoff_error_mm > 0.01
    assert path.offset_curve.dimension == 3
    summary = path.summary()
    assert summary["normal_source"] == "surface" and summary["lines"] == path.u.size


def test_path_over_the_apex_holds_c_and_never_flips(sphere: NurbsSurface) -> None:
    """A straight line through the pole: A passes through 0, C must not jump."""
    xy = np.column_stack([np.linspace(-15, 15, 31), np.zeros(31)])
    trace = trace_over_xy(sphere, xy)
    path = plan_five_axis(sphere, trace, FiveAxisParams(
        standoff_mm=H, feed_mm_min=1200, servo_period_s=0.002, segment_mm=1.0, pivot_mm=PIVOT))
    rows = _check_program(sphere, path.program, H, PIVOT)
    assert np.abs(np.diff(rows[:, 4])).max() < 1.0  # C stays put
    assert rows[0, 3] * rows[-1, 3] < 0  # A changes sign through the singularity


def test_circle_around_the_apex_turns_c_continuously(sphere: NurbsSurface) -> None:
    trace = trace_over_xy(sphere, _ellipse_xy(0.0, 0.0, 10.0, 10.0, 60))
    path = plan_five_axis(sphere, trace, FiveAxisParams(
        standoff_mm=H, feed_mm_min=1200, servo_period_s=0.002, segment_mm=1.0, pivot_mm=PIVOT))
    rows = _check_program(sphere, path.program, H, PIVOT)
    step = np.abs(np.diff(rows[:, 4]))
    assert step.max() < 10.0
    assert abs(rows[-1, 4] - rows[0, 4]) == pytest.approx(360.0, abs=1.0)  # one full turn


def test_principal_normal_option(sphere: NurbsSurface) -> None:
    """On a great circle the patent's principal normal is the surface normal; on the
    parallel plane section y = 10 it points to that circle's centre (0, 10, 0) and misses
    the surface normal by asin(10 / R): the planner reports which one it used."""
    params = FiveAxisParams(standoff_mm=H, feed_mm_min=1200, servo_period_s=0.002,
                            segment_mm=2.0, normal_source="principal")
    for y, expected in ((0.0, 0.0), (10.0, np.degrees(np.arcsin(10.0 / 40.0)))):
        xy = np.column_stack([np.linspace(-15, 15, 31), np.full(31, y)])
        path = plan_five_axis(sphere, trace_over_xy(sphere, xy), params)
        assert path.normal_source == "principal"
        assert path.max_normal_error_deg == pytest.approx(expected, abs=0.05)


def test_principal_normal_on_straight_trace_is_an_error(sphere: NurbsSurface) -> None:
    from app.geometry.nurbs import NurbsCurve

    z = np.sqrt(40.0**2 - 2.0**2)
    line = NurbsCurve(1, np.array([0, 0, 1, 1.0]), np.array([[0, -2, z], [0, 2, z]]))
    with pytest.raises((DegenerateTraceError, TraceOffSurfaceError)) as info:
        plan_five_axis(sphere, line, FiveAxisParams(normal_source="principal",
                                                    on_surface_tol_mm=0.1))
    assert info.value.field in ("params.normal_source", "trace")


def test_a_limit_exceeded_is_a_typed_error(sphere: NurbsSurface) -> None:
    trace = trace_over_xy(sphere, _ellipse_xy(4.0, 2.0, 14.0, 9.0))
    with pytest.raises(AxisLimitError) as info:
        plan_five_axis(sphere, trace, FiveAxisParams(a_limits_deg=(-10.0, 10.0),
                                                     segment_mm=2.0))
    assert info.value.field == "params.a_limits_deg"
    assert info.value.value["a_deg"] > 10.0


def test_trace_leaving_the_surface_is_a_typed_error(sphere: NurbsSurface) -> None:
    from app.geometry.fitting import interpolate_curve

    x = np.linspace(0, 40, 20)  # runs past the patch edge at x = 25
    pts = np.column_stack([x, np.zeros_like(x), np.sqrt(np.maximum(45.0**2 - x**2, 1.0))])
    with pytest.raises(TraceOffSurfaceError) as info:
        plan_five_axis(sphere, interpolate_curve(pts), FiveAxisParams(segment_mm=2.0))
    assert info.value.field == "trace" and info.value.value["distance_mm"] > 0.05
    with pytest.raises(TraceOffSurfaceError) as info:
        trace_over_xy(sphere, np.array([[0.0, 0.0], [30.0, 0.0]]))
    assert info.value.field == "trace.xy"


def test_bad_parameters_name_the_field() -> None:
    with pytest.raises(FiveAxisError) as info:
        FiveAxisParams(standoff_mm=-1.0)
    assert info.value.field == "params.standoff_mm"
    with pytest.raises(FiveAxisError) as info:
        FiveAxisParams(a_limits_deg=(30.0, -30.0))
    assert info.value.field == "params.a_limits_deg"
