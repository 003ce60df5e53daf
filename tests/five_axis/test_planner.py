"""End-to-end checks of plan_five_axis, verified from the program TEXT alone."""

from __future__ import annotations

import numpy as np
import pytest

from app.five_axis import (
    AxisLimitError,
    DegenerateTraceError,
    FiveAxisError,
    FiveAxisParams,
    TraceOffSurfaceError,
    plan_five_axis,
)
from app.five_axis.kinematics import (
    machine_to_workpiece,
    rotation_matrices,
)
from app.five_axis.trace import trace_over_xy
from app.geometry.fitting import fit_surface
from app.geometry.nurbs_surface import NurbsSurface
from tests.five_axis.conftest import SPHERE_R
from tests.helpers.gcode_words import g1_rows

H = 0.5
PIVOT = (5.0, -3.0, -20.0)


def _ellipse_xy(cx: float, cy: float, ax: float, by: float, n: int = 40) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n)
    return np.column_stack([cx + ax * np.cos(t), cy + by * np.sin(t)])


def _check_program(surface: NurbsSurface, text: str, h: float, pivot: tuple) -> np.ndarray:
    rows = g1_rows(text)
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
    params = FiveAxisParams(standoff_mm=H, feed_mm_min=1200, period_s=0.002,
                            segment_mm=1.0, pivot=PIVOT)
    path = plan_five_axis(sphere, trace, params)
    rows = _check_program(sphere, path.program, H, PIVOT)
    assert rows.shape[0] == path.u.size
    assert np.abs(np.diff(rows[:, 4])).max() <= 180.0
    assert path.figures.max_normal_error_deg < 0.05 and path.figures.max_standoff_error_mm < 1e-3
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
    nominal = g1_rows(path.nominal_program)
    assert not np.any(nominal[:, 3:5]) and all(" A" not in line for line in path.nominal_program.splitlines())
    assert path.figures.nominal_max_normal_error_deg > 10.0
    assert path.figures.nominal_max_standoff_error_mm > 0.01
    assert path.offset_curve.dimension == 3
    figures = path.figures
    assert figures.normal_source == "surface" and figures.lines == path.u.size == rows.shape[0]
    assert figures.a_range_deg == pytest.approx([rows[:, 3].min(), rows[:, 3].max()], abs=1e-9)
    assert figures.feed_fluctuation_pct == pytest.approx(100.0 * figures.feed_fluctuation) \
        == pytest.approx(100.0 * path.feed.max_rel)


def test_path_over_the_apex_holds_c_and_never_flips(sphere: NurbsSurface) -> None:
    """A straight line through the pole: A passes through 0, C must not jump."""
    xy = np.column_stack([np.linspace(-15, 15, 31), np.zeros(31)])
    trace = trace_over_xy(sphere, xy)
    path = plan_five_axis(sphere, trace, FiveAxisParams(
        standoff_mm=H, feed_mm_min=1200, period_s=0.002, segment_mm=1.0, pivot=PIVOT))
    rows = _check_program(sphere, path.program, H, PIVOT)
    assert np.abs(np.diff(rows[:, 4])).max() < 1.0  # C stays put
    assert rows[0, 3] * rows[-1, 3] < 0  # A changes sign through the singularity


def test_circle_around_the_apex_turns_c_continuously(sphere: NurbsSurface) -> None:
    trace = trace_over_xy(sphere, _ellipse_xy(0.0, 0.0, 10.0, 10.0, 60))
    path = plan_five_axis(sphere, trace, FiveAxisParams(
        standoff_mm=H, feed_mm_min=1200, period_s=0.002, segment_mm=1.0, pivot=PIVOT))
    rows = _check_program(sphere, path.program, H, PIVOT)
    step = np.abs(np.diff(rows[:, 4]))
    assert step.max() < 10.0
    assert abs(rows[-1, 4] - rows[0, 4]) == pytest.approx(360.0, abs=1.0)  # one full turn


def test_principal_normal_option(sphere: NurbsSurface) -> None:
    """On a great circle the patent's principal normal is the surface normal; on the
    parallel plane section y = 10 it points to that circle's centre (0, 10, 0) and misses
    the surface normal by asin(10 / R): the planner reports which one it used."""
    params = FiveAxisParams(standoff_mm=H, feed_mm_min=1200, period_s=0.002,
                            segment_mm=2.0, normal="principal")
    for y, expected in ((0.0, 0.0), (10.0, np.degrees(np.arcsin(10.0 / 40.0)))):
        xy = np.column_stack([np.linspace(-15, 15, 31), np.full(31, y)])
        path = plan_five_axis(sphere, trace_over_xy(sphere, xy), params)
        assert path.figures.normal_source == "principal"
        assert path.figures.max_normal_error_deg == pytest.approx(expected, abs=0.05)


def test_principal_normal_on_straight_trace_is_an_error(sphere: NurbsSurface) -> None:
    from app.geometry.nurbs import NurbsCurve

    z = np.sqrt(40.0**2 - 2.0**2)
    line = NurbsCurve(1, np.array([0, 0, 1, 1.0]), np.array([[0, -2, z], [0, 2, z]]))
    with pytest.raises((DegenerateTraceError, TraceOffSurfaceError)) as info:
        plan_five_axis(sphere, line, FiveAxisParams(normal="principal",
                                                    on_surface_tol_mm=0.1))
    assert info.value.field in ("params.normal", "trace")


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


# ---------------------------------------------------------------- the A = 0 singularity
def _line_over_apex(offset_mm: float, angle_deg: float = 30.0, half: float = 15.0,
                    k: int = 31) -> tuple[np.ndarray, np.ndarray]:
    """Plan-view points (k,2) of a straight line at ``angle_deg`` passing ``offset_mm``
    beside the apex (0, 0), and the line's unit plan-view normal (2,)."""
    t = np.radians(angle_deg)
    along, across = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])
    s = np.linspace(-half, half, k)
    return s[:, None] * along + offset_mm * across, across


def _midpoint_tips(text: str, pivot: tuple) -> np.ndarray:
    """Workpiece tip (m,3) halfway through every move: all five axes move linearly."""
    rows = g1_rows(text)
    mid = 0.5 * (rows[1:] + rows[:-1])
    return machine_to_workpiece(mid[:, :3], np.radians(mid[:, 3]), np.radians(mid[:, 4]),
                                np.array(pivot))


def _measured_sphere(noise_mm: float = 0.005, n: int = 20, half: float = 15.0) -> NurbsSurface:
    """A "measured" cap: least-squares 12 x 12 fit of noisy sphere heights on an n x n grid,
    so that its pole is not exactly at (0, 0)."""
    x = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    zz = np.sqrt(SPHERE_R**2 - xx**2 - yy**2)
    zz += np.random.default_rng(3).normal(0.0, noise_mm, zz.shape)
    return fit_surface(np.stack([xx, yy, zz], axis=-1), 12, 12).surface


@pytest.mark.parametrize(("surface_kind", "offset_mm", "angle_deg"), [
    ("sphere", 0.0, 30.0), ("sphere", 0.1, 30.0), ("sphere", 0.1, 90.0), ("measured", 0.0, 0.0),
    ("measured", 0.0, 30.0)])
def test_straight_trace_over_the_apex_keeps_the_tip_on_the_path(
        sphere: NurbsSurface, surface_kind: str, offset_mm: float, angle_deg: float) -> None:
    """Through the apex and 0.1 mm beside it: exact normals would swing C by up to
    ~180 deg within a millimetre and the tip leaves the path between lines (0.2-1.5 mm
    beside the apex, 40-90 um over a measured apex).  From the program text alone: halfway
    through every move the tip is h above the surface and over the plan-view line, to
    10 um; at every line it is h +- 1 um above the surface."""
    surface = sphere if surface_kind == "sphere" else _measured_sphere()
    xy, across = _line_over_apex(offset_mm, angle_deg, half=12.0, k=25)
    params = FiveAxisParams(standoff_mm=H, feed_mm_min=1200, period_s=0.002,
                            segment_mm=0.5, pivot=PIVOT, pole_window_deg=0.5)  # the wide window
    path = plan_five_axis(surface, trace_over_xy(surface, xy), params)
    rows = g1_rows(path.program)
    inv = surface.invert(_midpoint_tips(path.program, PIVOT))
    assert np.abs(inv.distance - H).max() < 0.01
    assert np.abs(inv.closest[:, :2] @ across - offset_mm).max() < 0.01
    assert path.figures.max_midpoint_error_mm < 0.01
    assert np.abs(np.diff(rows[:, 4])).max() < 10.0 and path.figures.max_c_step_deg < 10.0
    xyz, a, c = rows[:, :3], np.radians(rows[:, 3]), np.radians(rows[:, 4])
    assert np.abs(surface.invert(machine_to_workpiece(xyz, a, c, np.array(PIVOT))).distance
                  - H).max() < 1e-3
    # the nozzle axis leaves the normal only inside the pole window, by at most the
    # normal's tilt there (~ offset / R on the sphere)
    assert path.figures.max_normal_error_deg <= params.pole_window_deg
    if surface_kind == "sphere":
        assert path.figures.max_normal_error_deg < max(0.05, np.degrees(offset_mm / SPHERE_R) + 0.01)
    assert rows[0, 3] * rows[-1, 3] < 0  # A changes sign instead of C turning


def test_exact_normals_beside_the_apex_are_kept_by_splitting_lines(sphere: NurbsSurface) -> None:
    """pole_window_deg = 0: every line is exactly normal; the big C moves beside the
    pole are split until the midpoint tip error is below the tolerance."""
    xy, across = _line_over_apex(0.1)
    trace = trace_over_xy(sphere, xy)
    base = {"standoff_mm": H, "feed_mm_min": 1200, "period_s": 0.002, "segment_mm": 1.0,
            "pivot": PIVOT, "pole_window_deg": 0.0}
    path = plan_five_axis(sphere, trace, FiveAxisParams(**base))
    unsplit = plan_five_axis(sphere, trace, FiveAxisParams(**base, max_split_rounds=0))
    assert unsplit.figures.max_midpoint_error_mm > 0.1 and unsplit.figures.split_lines == 0
    assert path.figures.max_midpoint_error_mm < 0.01 < path.figures.split_lines
    assert path.u.size == unsplit.u.size + path.figures.split_lines
    tips = _midpoint_tips(path.program, PIVOT)
    radius = np.linalg.norm(tips, axis=1)
    assert np.abs(radius - (SPHERE_R + H)).max() < 0.01
    assert np.abs((tips * (SPHERE_R / radius)[:, None])[:, :2] @ across - 0.1).max() < 0.01
    _check_program(sphere, path.program, H, PIVOT)  # normals within 0.05 deg at every line
    # the price: C turns ~180 deg within a millimetre, far faster than with the window
    windowed = plan_five_axis(sphere, trace, FiveAxisParams(**{**base, "pole_window_deg": 0.5}))
    assert path.figures.max_c_speed_deg_s > 5 * windowed.figures.max_c_speed_deg_s
    # inverse-time F still adds up to the print time
    f = g1_rows(path.program)[1:, 5]
    assert (1.0 / f).sum() * 60.0 == pytest.approx(path.figures.duration_s, rel=1e-3)
    assert path.figures.pole_lines == 0


def test_dispense_commands_follow_the_approach_and_the_last_move(sphere: NurbsSurface) -> None:
    trace = trace_over_xy(sphere, _ellipse_xy(4.0, 2.0, 14.0, 9.0))
    fast = {"feed_mm_min": 1200, "period_s": 0.002, "segment_mm": 2.0, "safe_z_mm": 80.0}
    params = FiveAxisParams(**fast, dispense_on="M106 S255", dispense_off="M107")
    path = plan_five_axis(sphere, trace, params)
    for text in (path.program, path.nominal_program):
        lines = text.splitlines()
        g1 = [i for i, line in enumerate(lines) if line.startswith("G1 ")]
        assert lines.count("M106 S255") == 1 and lines.count("M107") == 1
        assert lines.index("M106 S255") == g1[0] + 1 and lines.index("M107") == g1[-1] + 1
    plain = plan_five_axis(sphere, trace, FiveAxisParams(**fast))
    assert "M106 S255" not in plain.program and "M107" not in plain.nominal_program
    assert [ln for ln in path.program.splitlines() if ln not in ("M106 S255", "M107")] \
        == plain.program.splitlines()
    for bad in ("M8\nG28", "  ", 8):
        with pytest.raises(FiveAxisError) as info:
            FiveAxisParams(dispense_on=bad)
        assert info.value.field == "params.dispense_on"
