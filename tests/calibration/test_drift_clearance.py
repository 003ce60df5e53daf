"""Drift timing and correction, re-touch schedule, nozzle clearance, re-check agreement."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.calibration import (
    CalibrationError,
    DriftTrack,
    disagreements,
    drift_offsets,
    nozzle_clearance,
    retouch_schedule,
    touch_times,
)


def test_touch_times_follow_the_probe_kinematics():
    # from (0, 0, 20): up/down to safe 10 (10 mm at 600 mm/min = 1 s), across 30 mm (3 s),
    # probe down 10 - 2 = 8 mm at 60 mm/min (8 s) -> 12 s; retract 8 mm (0.8 s);
    # second: safe 10 -> 12 (0.2 s), across 40 mm (4 s), probe 12 -> 5 (7 s)
    points = [[30.0, 0.0, 2.0], [30.0, 40.0, 5.0]]
    t = touch_times(points, [10.0, 12.0], [0.0, 0.0], 600.0, 60.0, (0.0, 0.0, 20.0))
    assert t == pytest.approx([12.0, 12.0 + 0.8 + 0.2 + 4.0 + 7.0])
    # a contact expected below the target: the move ends at the target
    t2 = touch_times([[0.0, 0.0, -5.0]], [10.0], [1.0], 600.0, 60.0, (0.0, 0.0, 10.0))
    assert t2 == pytest.approx([9.0])


def test_drift_offsets_are_exact_on_a_linear_drift_and_constant_outside():
    rate = 0.001 / 60            # 1 um/min in mm/s
    track = DriftTrack(times_s=(0.0, 120.0, 240.0), pad_z_mm=tuple(2.0 - rate * t for t in (0.0, 120.0, 240.0)))
    times = np.array([0.0, 33.0, 150.0, 239.0])
    assert drift_offsets(track, times, 2.0) == pytest.approx(rate * times, abs=1e-15)
    assert drift_offsets(track, [-5.0, 400.0], 2.0) == pytest.approx([0.0, rate * 240.0], abs=1e-15)
    with pytest.raises(CalibrationError):
        DriftTrack(times_s=(1.0, 0.0), pad_z_mm=(0.0, 0.0))


def test_retouch_schedule():
    times = [0.0, 50.0, 100.0, 130.0, 200.0, 251.0, 260.0]
    assert retouch_schedule(times, 120.0) == [0, 3, 5, 7]     # 130 - 0 > 120, 251 - 130 > 120
    assert retouch_schedule(times, 10.0) == [0, 1, 2, 3, 4, 5, 7]
    assert retouch_schedule([], 60.0) == []


def plane(slope_deg, azimuth_deg=0.0):
    g = math.tan(math.radians(slope_deg)) * np.array([math.cos(math.radians(azimuth_deg)),
                                                     math.sin(math.radians(azimuth_deg))])
    return lambda xy: xy @ g + 1.0


@pytest.mark.parametrize("slope", [0.0, 10.0, 30.0, 45.0])
@pytest.mark.parametrize("azimuth", [0.0, 17.0, 100.0])
def test_clearance_on_a_plane_is_the_standoff_minus_the_slope_term(slope, azimuth):
    height = plane(slope, azimuth)
    tips = np.array([[x, 2.0, 0.0] for x in (0.0, 3.0, 6.0)])
    tips[:, 2] = height(tips[:, :2]) + 0.05                      # 50 um standoff at the tip
    out = nozzle_clearance(tips, height, 0.8)
    expected = 0.05 - 0.4 * math.tan(math.radians(slope))
    # exact on a plane: the rim's highest point is found from the sinusoid through three rim samples
    assert out.per_point_mm == pytest.approx(np.full(3, expected), abs=1e-12)
    assert out.min_mm == pytest.approx(expected, abs=1e-12)
    assert out.point_mm[2] == pytest.approx(height(np.array([out.point_mm[:2]]))[0])


def test_clearance_names_the_closest_tip_on_a_bump():
    def bump(xy):
        return 0.3 * np.exp(-((xy[:, 0] - 5.0) ** 2 + xy[:, 1] ** 2) / 0.5)
    tips = np.array([[x, 0.0, 0.35 + 0.02 * abs(x - 5.0)] for x in np.linspace(0.0, 10.0, 41)])
    out = nozzle_clearance(tips, bump, 1.0)
    assert tips[out.index][0] == pytest.approx(5.0)
    assert out.min_mm == pytest.approx(0.05, abs=1e-9)
    assert out.point_mm == pytest.approx((5.0, 0.0, 0.3))
    # 0.25 mm aside the body still covers the top of the bump: the tip's own standoff would say 0.064
    assert out.per_point_mm[19] == pytest.approx(0.35 + 0.005 - 0.3, abs=1e-9)
    off = np.array([[4.5, 0.0, 0.2]])   # the rim reaches the top of the bump
    assert nozzle_clearance(off, bump, 1.0).min_mm == pytest.approx(-0.1, abs=1e-3)


@settings(max_examples=30, deadline=None)
@given(slope=st.floats(0.0, 50.0), azimuth=st.floats(0.0, 360.0), d=st.floats(0.1, 2.0))
def test_clearance_on_random_planes_is_exact(slope, azimuth, d):
    height = plane(slope, azimuth)
    tip = np.array([[1.0, 1.0, height(np.array([[1.0, 1.0]]))[0] + 0.1]])
    out = nozzle_clearance(tip, height, d)
    term = d / 2 * math.tan(math.radians(slope))
    assert out.min_mm == pytest.approx(0.1 - term, abs=1e-12)


def test_disagreements():
    old = {"x": 12.3, "y": -4.1, "z": -8.7}
    new = {"x": 12.3005, "y": -4.1, "z": -8.69}
    got = disagreements(old, new, {"x": 0.0005, "z": 0.001}, {"x": 0.0005, "z": 0.001})
    assert set(got) == {"z"} and got["z"] == pytest.approx(0.01)
    assert disagreements(old, new, {}, {}, floor_mm=0.02) == {}
