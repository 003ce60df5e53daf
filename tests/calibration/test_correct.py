"""Radius and pre-travel compensation of vertical readings on planes (exact) and tilted normals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.calibration import CalibrationError, PretravelModel, ProbeCalibration, surface_heights, tilted_normals
from tests.calibration.forward import TrueProbe, plane_reading


def calibration(r=0.5, p0=0.015, a=0.0, b=0.0) -> ProbeCalibration:
    return ProbeCalibration(r, PretravelModel(p0, a, b), (0.0, 0.0, 0.0), None)


def test_the_issue_example_32_um_becomes_nothing():
    """r = 0.5 mm at 20 deg: the uncorrected error r (1/cos - 1) is 32 um."""
    reading, n = plane_reading(10.0, 5.0, 3.0, 20.0, 30.0, TrueProbe(r=0.5, p0=0.0))
    raw_error = reading[2] - 0.5 - 3.0           # today's ideal correction: ball centre - r
    assert raw_error * 1e3 == pytest.approx(32.1, abs=0.1)
    out = surface_heights(reading[None], n[None], calibration(0.5, 0.0))
    assert abs(out.z_mm[0] - 3.0) < 1e-8          # < 0.01 um
    assert out.correction_mm[0] == pytest.approx(3.0 - reading[2])


@pytest.mark.parametrize("slope", [0.0, 5.0, 20.0, 35.0, 60.0])
@pytest.mark.parametrize("azimuth", [0.0, 70.0, 200.0])
def test_planes_of_several_slopes_are_exact(slope, azimuth):
    probe = TrueProbe(r=0.5, p0=0.015, a=0.003, b=-0.002)
    reading, n = plane_reading(-4.0, 7.0, 1.25, slope, azimuth, probe)
    out = surface_heights(reading[None], n[None], calibration(0.5, 0.015, 0.003, -0.002))
    assert out.z_mm[0] == pytest.approx(1.25, abs=1e-9)
    # the contact lies on the plane, r from the ball centre at first contact
    contact = out.contact_mm[0]
    assert (contact - np.array([-4.0, 7.0, 1.25])) @ n == pytest.approx(0.0, abs=1e-9)
    centre = reading + [0.0, 0.0, probe.delta(n, None)]
    assert np.linalg.norm(centre - contact) == pytest.approx(0.5, abs=1e-12)


def test_each_part_switches_off_for_ablation_and_none_is_the_ideal_probe():
    probe = TrueProbe(r=0.5, p0=0.015)
    reading, n = plane_reading(0.0, 0.0, 0.0, 30.0, 0.0, probe)
    cal = calibration()
    full = surface_heights(reading[None], n[None], cal).z_mm[0]
    no_radius = surface_heights(reading[None], n[None], cal, radius=False).z_mm[0]
    no_pre = surface_heights(reading[None], n[None], cal, pretravel=False).z_mm[0]
    assert full == pytest.approx(0.0, abs=1e-12)
    assert no_radius - full == pytest.approx(0.5 / math.cos(math.radians(30)))
    assert full - no_pre == pytest.approx(0.015)
    ideal = surface_heights(reading[None], n[None], None)
    assert ideal.z_mm[0] == reading[2] and ideal.correction_mm[0] == 0.0
    assert ideal.contact_mm[0] == pytest.approx(reading)


def test_a_normal_facing_down_is_refused_by_index():
    with pytest.raises(CalibrationError) as err:
        surface_heights([[0, 0, 1], [0, 0, 1]], [[0, 0, 1], [1, 0, -0.2]], calibration())
    assert err.value.field == "normals[1]"


@settings(max_examples=60, deadline=None)
@given(slope=st.floats(0.0, 70.0), azimuth=st.floats(-180.0, 180.0), r=st.floats(0.0, 1.0),
       p0=st.floats(0.0, 0.05), lobe=st.floats(-0.01, 0.01), h=st.floats(-50.0, 50.0))
def test_surface_heights_inverts_the_forward_model(slope, azimuth, r, p0, lobe, h):
    probe = TrueProbe(r=r, p0=p0, a=lobe, b=-lobe / 2)
    reading, n = plane_reading(3.0, -2.0, h, slope, azimuth, probe)
    out = surface_heights(reading[None], n[None], calibration(r, p0, lobe, -lobe / 2))
    assert out.z_mm[0] == pytest.approx(h, abs=1e-9)


def test_tilted_normals_add_the_deviation_gradient():
    nominal = np.array([[0.0, 0.0, 1.0], [math.sin(0.3), 0.0, math.cos(0.3)]])
    # a flat nominal tilted by a deviation of gradient (0.1, -0.2): n ~ (-0.1, 0.2, 1)
    out = tilted_normals(nominal, [[0.1, -0.2], [0.0, 0.0]])
    assert out[0] == pytest.approx(np.array([-0.1, 0.2, 1.0]) / math.sqrt(1.05))
    assert out[1] == pytest.approx(nominal[1])
    # a deviation of slope tan(0.3) on the tilted nominal brings it back to flat
    back = tilted_normals(nominal[1:], [[math.tan(0.3), 0.0]])
    assert back[0] == pytest.approx([0.0, 0.0, 1.0], abs=1e-12)
