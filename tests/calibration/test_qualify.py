"""Probe qualification: recover r, p0, lobing and the sphere centre from an independent forward model."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.calibration import CalibrationError, ProbeCalibration, Touch, fit_qualification, plan_qualification
from tests.calibration.forward import TrueProbe, sphere_reading

NOMINAL = (100.0, 50.0, 10.0)
TRUE = (100.25, 49.7, 10.3)      # off its nominal place by 0.49 mm (the plan allows 0.5)
DIAMETER = 10.0
PAD_NOMINAL = (80.0, 50.0, 2.0)
PAD_TRUE_Z = 2.3


def readings_for(touches, probe: TrueProbe, rng=None, centre=TRUE, drift=None):
    """drift: (times (n,) s, rate mm/s): the machine is rate * t higher than commanded, so
    the geometry sits rate * t lower in commanded coordinates."""
    out = []
    for k, t in enumerate(touches):
        e = 0.0 if drift is None else drift[1] * drift[0][k]
        if t.kind == "pad":
            out.append([t.start_mm[0], t.start_mm[1],
                        PAD_TRUE_Z - e + probe.r - probe.delta((0.0, 0.0, 1.0), rng)])
        else:
            hit = sphere_reading(t.start_mm, t.target_mm, np.subtract(centre, (0, 0, e)), DIAMETER / 2, probe, rng)
            assert hit is not None, f"the plan missed the sphere: {t}"
            out.append(hit)
    return np.array(out)


def plan(r=0.5):
    return plan_qualification(NOMINAL, DIAMETER, r, PAD_NOMINAL)


def test_the_plan_has_the_requested_touches_and_safe_starts():
    touches = plan()
    rng = np.random.default_rng(0)
    kinds = [t.kind for t in touches]
    assert kinds[:3] == kinds[-3:] == ["pad"] * 3 and kinds.count("pad") == 6 and kinds.count("equator") == 16
    assert kinds.count("cap") == 2 + 4 * 8          # the top twice: first and last of the caps
    caps = [t for t in touches if t.kind == "cap"]
    assert caps[0] == caps[-1] and len({t.start_mm for t in caps}) == 1 + 4 * 8
    for t in touches:
        if t.kind == "cap":
            assert t.direction == pytest.approx([0, 0, -1])
        if t.kind == "equator":
            assert t.direction[2] == 0 and t.start_mm[2] == NOMINAL[2]
            # radial: the move points at the nominal centre
            to_c = np.subtract(NOMINAL, t.start_mm)
            assert np.cross(to_c, t.direction) == pytest.approx([0, 0, 0], abs=1e-12)
        if t.kind in ("cap", "equator"):
            # for a sphere up to 0.5 mm off its place in any direction: the start is outside the
            # ball-swept sphere, the move travels >= approach (1 mm) before it touches, and it
            # touches before its end
            for v in rng.normal(size=(200, 3)):
                c = np.add(NOMINAL, 0.5 * v / np.linalg.norm(v))
                assert np.linalg.norm(np.subtract(t.start_mm, c)) > DIAMETER / 2 + 0.5
                hit = sphere_reading(t.start_mm, t.target_mm, c, DIAMETER / 2, TrueProbe(p0=0.0))
                assert hit is not None and np.linalg.norm(hit - t.start_mm) >= 1.0 - 1e-9


def test_zero_noise_recovers_everything_exactly():
    probe = TrueProbe(r=0.5, p0=0.015)
    touches = plan()
    cal = fit_qualification(touches, readings_for(touches, probe), DIAMETER)
    assert cal.ball_radius_mm == pytest.approx(0.5, abs=1e-6)
    assert cal.pretravel.p0_mm == pytest.approx(0.015, abs=1e-6)
    assert cal.pretravel.lobing_mm < 1e-6
    assert cal.sphere_centre_mm == pytest.approx(TRUE, abs=1e-6)
    assert cal.pad_reading_z_mm == pytest.approx(PAD_TRUE_Z + 0.5 - 0.015, abs=1e-9)
    assert cal.pad_surface_z_mm() == pytest.approx(PAD_TRUE_Z, abs=1e-6)
    assert cal.residual_rms_mm < 1e-8
    assert cal.touches == len(touches)


def test_lobing_is_recovered():
    probe = TrueProbe(r=0.75, p0=0.012, a=0.004, b=-0.003)
    touches = plan(0.75)
    cal = fit_qualification(touches, readings_for(touches, probe), DIAMETER)
    assert cal.ball_radius_mm == pytest.approx(0.75, abs=1e-6)
    assert (cal.pretravel.p0_mm, cal.pretravel.cos3_mm, cal.pretravel.sin3_mm) == pytest.approx(
        (0.012, 0.004, -0.003), abs=1e-6)
    assert cal.pretravel.lobing_mm == pytest.approx(0.005, abs=1e-6)


def test_radius_and_pretravel_are_separable_only_with_both_kinds_of_touch():
    """Two probes with the same R + r - p0 (the equator sees only that) differ on the caps, and back."""
    touches = plan()
    one, two = TrueProbe(r=0.5, p0=0.015), TrueProbe(r=0.53, p0=0.045)
    a, b = (fit_qualification(touches, readings_for(touches, p), DIAMETER, lobing=False) for p in (one, two))
    assert a.ball_radius_mm == pytest.approx(0.5, abs=1e-6) and b.ball_radius_mm == pytest.approx(0.53, abs=1e-6)
    assert a.pretravel.p0_mm == pytest.approx(0.015, abs=1e-6) and b.pretravel.p0_mm == pytest.approx(0.045, abs=1e-6)
    # on a sphere at its nominal place the equator readings of the two probes coincide: radial
    # horizontal touches see only R + r - p0
    eq = [i for i, t in enumerate(touches) if t.kind == "equator"]
    at_nominal = [readings_for(touches, p, centre=NOMINAL)[eq] for p in (one, two)]
    assert at_nominal[0] == pytest.approx(at_nominal[1], abs=1e-12)
    # caps alone: radius and pre-travel trade against the centre height -> refused
    caps = [t for t in touches if t.kind == "cap"]
    with pytest.raises(CalibrationError) as err:
        fit_qualification(caps, readings_for(caps, one), DIAMETER, lobing=False)
    assert err.value.field == "touches"


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noisy_recovery_lies_within_three_sigma(seed):
    rng = np.random.default_rng(seed)
    probe = TrueProbe(r=0.5, p0=0.015, a=0.002, b=0.001, scatter=0.002, noise=0.001)
    touches = plan_qualification(NOMINAL, DIAMETER, 0.5, PAD_NOMINAL, per_ring=12, equator=24)
    cal = fit_qualification(touches, readings_for(touches, probe, rng), DIAMETER)
    sigma = math.hypot(0.002, 0.001)
    assert cal.residual_rms_mm == pytest.approx(sigma, rel=0.4)
    truth = {"ball_radius_mm": 0.5, "p0_mm": 0.015, "cos3_mm": 0.002, "sin3_mm": 0.001}
    got = {"ball_radius_mm": cal.ball_radius_mm, "p0_mm": cal.pretravel.p0_mm,
           "cos3_mm": cal.pretravel.cos3_mm, "sin3_mm": cal.pretravel.sin3_mm}
    for key, value in truth.items():
        assert 0 < cal.std[key] < 0.003
        assert abs(got[key] - value) < 3 * cal.std[key] + 1e-7, key
    for k in range(3):
        assert abs(cal.sphere_centre_mm[k] - TRUE[k]) < 3 * cal.std[f"centre_{'xyz'[k]}_mm"] + 1e-7


def test_the_reported_std_matches_the_scatter_of_repeated_calibrations():
    probe = TrueProbe(r=0.5, p0=0.015, scatter=0.002, noise=0.001)
    touches = plan()
    rng = np.random.default_rng(7)
    fits = [fit_qualification(touches, readings_for(touches, probe, rng), DIAMETER, lobing=False) for _ in range(40)]
    radii = np.array([f.ball_radius_mm for f in fits])
    reported = np.median([f.std["ball_radius_mm"] for f in fits])
    assert radii.std(ddof=1) == pytest.approx(reported, rel=0.4)
    assert abs(radii.mean() - 0.5) < 3 * reported / math.sqrt(len(fits)) + 1e-7


def test_an_absurd_reading_is_refused_naming_the_touch():
    touches = plan()
    readings = readings_for(touches, TrueProbe())
    bad = 9
    readings[bad] -= 0.2 * touches[bad].direction      # on its line, 0.2 mm early (dust on the sphere)
    with pytest.raises(CalibrationError) as err:
        fit_qualification(touches, readings, DIAMETER)
    assert err.value.field == f"readings[{bad}]"
    off = float(re.search(r"is (-?[0-9.]+) mm", err.value.message).group(1))
    assert abs(off) == pytest.approx(0.2, abs=0.005)           # reported along the move (to first order)
    off = readings_for(touches, TrueProbe())
    off[12] += (3.0, 0.0, 0.0)
    with pytest.raises(CalibrationError) as err:
        fit_qualification(touches, off, DIAMETER)
    assert err.value.field == "readings[12]"


def test_calibrations_round_trip_through_json():
    import json
    touches = plan()
    cal = fit_qualification(touches, readings_for(touches, TrueProbe(a=0.001)), DIAMETER)
    again = ProbeCalibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    assert again == cal
    assert Touch.from_dict(touches[5].to_dict()) == touches[5]
    with pytest.raises(CalibrationError) as err:
        ProbeCalibration.from_dict({"ball_radius_mm": "x", "pretravel": {"p0_mm": 0}, "sphere_centre_mm": [0, 0, 0]})
    assert err.value.field == "ball_radius_mm"


def test_a_drift_during_the_qualification_is_fitted_from_the_touch_times():
    probe = TrueProbe(r=0.5, p0=0.015, a=0.003)
    touches = plan()
    rng = np.random.default_rng(5)
    times = np.cumsum(rng.uniform(2.0, 4.0, len(touches))) + 100.0      # ~3 s a touch, s
    rate = 0.001 / 60                                                    # 1 um/min
    readings = readings_for(touches, probe, drift=(times, rate))
    # without the times: the palindromic order keeps r and p0 within a fraction of a micron
    blind = fit_qualification(touches, readings, DIAMETER)
    assert abs(blind.ball_radius_mm - 0.5) < 0.0003 and abs(blind.pretravel.p0_mm - 0.015) < 0.0003
    # ... where touching ring after ring bends the curvature: r and p0 move by microns (in step)
    by_ring = sorted(range(len(touches)), key=lambda i: (touches[i].kind != "pad", touches[i].kind == "equator",
                                                          -touches[i].start_mm[2]))
    ringwise = [touches[i] for i in by_ring]
    skewed = fit_qualification(ringwise, readings_for(ringwise, probe, drift=(times, rate)), DIAMETER)
    assert abs(skewed.ball_radius_mm - 0.5) > 0.001
    assert (skewed.ball_radius_mm - 0.5) == pytest.approx(skewed.pretravel.p0_mm - 0.015, abs=0.0003)
    cal = fit_qualification(touches, readings, DIAMETER, times_s=times)
    assert cal.ball_radius_mm == pytest.approx(0.5, abs=1e-6)
    assert cal.pretravel.p0_mm == pytest.approx(0.015, abs=1e-6)
    assert cal.pretravel.cos3_mm == pytest.approx(0.003, abs=1e-6)
    assert cal.drift_mm_per_min == pytest.approx(0.001, abs=1e-7)
    # the centre and the pad reading refer to the first touch's drift
    e0 = rate * times[0]
    assert cal.sphere_centre_mm == pytest.approx(np.subtract(TRUE, (0, 0, e0)), abs=1e-6)
    assert cal.pad_reading_z_mm == pytest.approx(PAD_TRUE_Z - e0 + 0.5 - 0.015, abs=1e-6)
    assert ProbeCalibration.from_dict(cal.to_dict()) == cal


def test_a_ring_that_could_miss_the_sphere_is_refused():
    with pytest.raises(CalibrationError) as err:
        plan_qualification(NOMINAL, DIAMETER, 0.5, None, cap_rings_deg=(0, 30, 70))
    assert err.value.field == "cap_rings_deg" and err.value.value == [70.0]
    assert plan_qualification(NOMINAL, 25.4, 0.5, None, cap_rings_deg=(0, 30, 70))   # a bigger sphere allows it


@settings(max_examples=25, deadline=None)
@given(r=st.floats(0.25, 1.0), p0=st.floats(0.0, 0.05), a=st.floats(-0.01, 0.01), b=st.floats(-0.01, 0.01),
       offset=st.tuples(*[st.floats(-0.28, 0.28)] * 3), diameter=st.sampled_from([8.0, 10.0, 25.4]))
def test_qualification_inverts_the_forward_model(r, p0, a, b, offset, diameter):
    centre = np.add(NOMINAL, offset)               # up to 0.49 mm off its nominal place
    touches = plan_qualification(NOMINAL, diameter, r, None, cap_rings_deg=(0, 20, 35, 50))
    readings = [sphere_reading(t.start_mm, t.target_mm, centre, diameter / 2, TrueProbe(r=r, p0=p0, a=a, b=b))
                for t in touches]
    cal = fit_qualification(touches, np.array(readings), diameter)
    assert (cal.ball_radius_mm, cal.pretravel.p0_mm, cal.pretravel.cos3_mm, cal.pretravel.sin3_mm) == \
        pytest.approx((r, p0, a, b), abs=1e-7)
    assert cal.sphere_centre_mm == pytest.approx(centre, abs=1e-7)
