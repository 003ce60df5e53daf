"""Planner time estimates vs hand-computed trapezoids and junction speeds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.gcode.estimator import EstimatorError, MachineLimits, estimate_gcode, estimate_moves

LIM = MachineLimits(accel_mm_s2=1000.0, travel_accel_mm_s2=2000.0, junction_deviation_mm=0.05,
                    max_feed_mm_s=(500.0, 500.0, 10.0, 100.0),
                    max_accel_mm_s2=(1e5, 1e5, 1e5, 1e5))


def trapezoid(L, vi, vf, vn, a):
    """Hand formula: accelerate, cruise, decelerate (or the triangle if too short)."""
    if (vn ** 2 - vi ** 2) / (2 * a) + (vn ** 2 - vf ** 2) / (2 * a) <= L:
        return (vn - vi) / a + (vn - vf) / a + (L - (2 * vn ** 2 - vi ** 2 - vf ** 2)
                                                / (2 * a)) / vn
    vp = math.sqrt((2 * a * L + vi ** 2 + vf ** 2) / 2)
    return (vp - vi) / a + (vp - vf) / a


def test_single_move_trapezoid_and_triangle():
    assert estimate_gcode("G1 X100 E1 F6000\n", LIM).total_s == pytest.approx(1.1)
    # 2 mm at 100 mm/s, a = 1000: peak sqrt(2000) < 100 -> triangle 2*sqrt(2000)/1000
    assert estimate_gcode("G1 X2 E1 F6000\n", LIM).total_s == pytest.approx(
        2 * math.sqrt(2000) / 1000)


def test_travel_uses_travel_acceleration():
    t = estimate_gcode("G1 X100 F6000\n", LIM)
    assert t.total_s == pytest.approx(trapezoid(100, 0, 0, 100, 2000))
    assert t.print_s == 0 and t.travel_s == pytest.approx(t.total_s)


def test_corner_junction_deviation():
    for angle_deg in (30, 90, 135):
        th = math.radians(angle_deg)               # turn angle between the two moves
        x2, y2 = 100 + 100 * math.cos(th), 100 * math.sin(th)
        g = f"G1 X100 Y0 E1 F6000\nG1 X{x2:.9f} Y{y2:.9f} E2\n"
        cos_theta = -math.cos(th)
        s = math.sqrt(0.5 * (1 - cos_theta))
        vj = min(100.0, math.sqrt(1000 * 0.05 * s / (1 - s)))
        expect = 2 * trapezoid(100, 0, vj, 100, 1000)
        assert estimate_gcode(g, LIM).total_s == pytest.approx(expect, rel=1e-9)


def test_straight_continuation_and_reversal():
    straight = estimate_gcode("G1 X50 E1 F6000\nG1 X100 E2\n", LIM).total_s
    assert straight == pytest.approx(1.1)
    back = estimate_gcode("G1 X50 E1 F6000\nG1 X0 E2\n", LIM).total_s
    assert back == pytest.approx(2 * trapezoid(50, 0, 0, 100, 1000))


def test_lookahead_limits_entry_speed_over_short_moves():
    # many 0.1 mm collinear moves then a reversal: the planner must decelerate in time
    lines = ["G1 X0 F6000"] + [f"G1 X{0.1 * k:.1f} E{0.001 * k:.3f}"
                                    for k in range(1, 101)] + ["G1 X0 E0.2"]
    t = estimate_gcode("\n".join(lines) + "\n", LIM).total_s
    assert t == pytest.approx(2 * trapezoid(10, 0, 0, 100, 1000), rel=1e-9)


def test_modes_relative_e_g92_units_dwell_and_m204():
    g = "G21\nM83\nG91\nG1 X10 E1 F600\nG1 X10 E1\nG90\nG92 X0\nG1 X10 F600\nG4 P500\n"
    t = estimate_gcode(g, LIM)
    # relative 10 + 10 collinear printing, then a collinear 10 mm travel (G92 resets X to
    # 0, so X10 moves on by 10 mm): no stop at either junction, 10 mm/s through both
    expect = trapezoid(20, 0, 10, 10, 1000) + trapezoid(10, 10, 0, 10, 2000) + 0.5
    assert t.total_s == pytest.approx(expect)
    assert t.dwell_s == pytest.approx(0.5)
    inch = estimate_gcode("G20\nG1 X1 E0.1 F600\n", LIM).total_s
    assert inch == pytest.approx(trapezoid(25.4, 0, 0, 600 * 25.4 / 60, 1000))
    slower = estimate_gcode("M204 P100\nG1 X100 E1 F6000\n", LIM).total_s
    assert slower == pytest.approx(trapezoid(100, 0, 0, 100, 100))


def test_axis_feed_limit_and_layers():
    g = ";LAYER:0\nG1 Z5 F6000\n;LAYER:1\nG1 X10 E1\n"
    t = estimate_gcode(g, LIM)
    # Z capped at 10 mm/s; the 90-degree junction allows sqrt(a jd s/(1-s)) = 11.0 > 10
    assert t.layer_times[0] == pytest.approx(trapezoid(5, 0, 10, 10, 2000))
    assert t.layer_times[1] == pytest.approx(trapezoid(10, 10, 0, 100, 1000))



def test_m203_and_m201_set_the_named_axes_only():
    # the program caps X at 20 mm/s and 50 mm/s^2; Y, Z, E keep LIM's values
    head = "M203 X20\nM201 X50\n"
    along_x = estimate_gcode(head + "G1 X100 E1 F6000\n", LIM).total_s
    assert along_x == pytest.approx(trapezoid(100, 0, 0, 20, 50))
    along_y = estimate_gcode(head + "G1 Y100 E1 F6000\n", LIM).total_s
    assert along_y == pytest.approx(trapezoid(100, 0, 0, 100, 1000))


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=2, max_size=30),
       st.floats(5, 200))
def test_estimate_bounds(points, feed):
    pos = np.array([[x, y, 0.0, 0.0] for x, y in points])
    t = estimate_moves(pos, np.full(len(pos) - 1, feed), LIM)
    L = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)
    assert np.all(t >= L / feed - 1e-9)                          # never faster than feed
    # never slower than stopping at every junction
    assert t.sum() <= sum(trapezoid(x, 0, 0, feed, 2000) for x in L if x > 1e-12) + 1e-9


def test_bad_limits():
    with pytest.raises(EstimatorError):
        estimate_gcode("G1 X1 F600\n", MachineLimits(accel_mm_s2=0.0))


def test_command_times_put_each_move_s_time_on_its_command_and_sum_to_the_estimate():
    from app.gcode.estimator import command_times, estimate_gcode
    commands = ["G21", "G90", "G1 X10 F600", "M106", "G1 X10 Y10 F600", "G4 P0", "G1 X0 Y0 F1200"]
    times = command_times(commands)
    assert times.shape == (7,)
    assert times[[0, 1, 3, 5]].tolist() == [0.0, 0.0, 0.0, 0.0]            # no motion, no time
    assert times[2] == pytest.approx(1.0, rel=0.05) and times[4] == pytest.approx(1.0, rel=0.05)  # 10 mm at 10 mm/s
    assert times.sum() == pytest.approx(estimate_gcode("\n".join(commands)).total_s)
