"""Nozzle offsets: Z on the pad against the probe, XY from opposite body touches on the sphere."""

from __future__ import annotations

import numpy as np
import pytest

from app.calibration import (
    CalibrationError,
    NozzleCalibration,
    PretravelModel,
    ProbeCalibration,
    fit_nozzle_offset,
    fit_qualification,
    plan_nozzle_calibration,
    plan_qualification,
)
from app.calibration.nozzle import pad_grid
from tests.calibration.forward import TrueProbe, nozzle_pad_reading, nozzle_side_reading, sphere_reading

SPHERE = (100.25, 49.7, 10.3)           # true centre (probe frame), 0.49 mm off its nominal place
DIAMETER = 10.0
PAD_Z = 2.3                            # true pad top
PAD_NOMINAL = (80.0, 50.0, 2.0)
O_TRUE = (12.3, -4.1, -8.7)
O_NOMINAL = (12.0, -4.0, -8.5)
NOZZLE_D = 0.8


def probe_readings(touches, probe: TrueProbe, rng=None):
    out = []
    for t in touches:
        if t.kind == "pad":
            out.append([t.start_mm[0], t.start_mm[1], PAD_Z + probe.r - probe.delta((0.0, 0.0, 1.0), rng)])
        else:
            out.append(sphere_reading(t.start_mm, t.target_mm, SPHERE, DIAMETER / 2, probe, rng))
    return np.array(out)


def nozzle_readings(touches, probe: TrueProbe, offset=O_TRUE, noise=0.0, rng=None):
    out = []
    for t in touches:
        if t.kind == "pad":
            out.append(probe_readings([t], probe, rng)[0])
        elif t.kind == "nozzle_pad":
            out.append(nozzle_pad_reading(t.start_mm, offset, PAD_Z, noise, rng))
        else:
            out.append(nozzle_side_reading(t.start_mm, t.target_mm, offset, NOZZLE_D, SPHERE, DIAMETER / 2, noise, rng))
    return np.array(out)


def qualified(probe: TrueProbe, rng=None) -> ProbeCalibration:
    touches = plan_qualification((100, 50, 10), DIAMETER, 0.5, PAD_NOMINAL)
    return fit_qualification(touches, probe_readings(touches, probe, rng), DIAMETER)


def test_the_plan_orders_probe_pad_nozzle_pad_and_four_sides():
    cal = ProbeCalibration(0.5, PretravelModel(0.015), SPHERE, PAD_Z + 0.5 - 0.015)
    touches = plan_nozzle_calibration(cal, O_NOMINAL, NOZZLE_D, DIAMETER, PAD_NOMINAL)
    kinds = [t.kind for t in touches]
    # P N N P blocks over the two halves of the spots: probe and nozzle touches share their mean time
    assert kinds == ["pad", "pad", "nozzle_pad", "nozzle_pad", "nozzle_pad", "pad"] + ["nozzle_side"] * 8
    # the nozzle's pad spots are the probe's, through the nominal offset
    probe_spots = [t.start_mm[:2] for t in touches if t.kind == "pad"]
    nozzle_spots = [np.add(t.start_mm[:2], O_NOMINAL[:2]) for t in touches if t.kind == "nozzle_pad"]
    assert np.array(nozzle_spots) == pytest.approx(np.array(probe_spots))
    # within a block and along a side every touch after the first hops locally
    assert [t.local for t in touches] == [False, True, False, True, False, False] + [False, True] * 4
    for t in touches[6:]:
        tip = np.add(t.start_mm, O_NOMINAL)
        assert tip[2] == pytest.approx(SPHERE[2] - 0.3 * DIAMETER / 2)
        # the body starts clearance_mm outside the sphere
        assert np.hypot(*(tip[:2] - np.array(SPHERE[:2]))) == pytest.approx(DIAMETER / 2 + NOZZLE_D / 2 + 2.0)


def test_the_pad_spots_form_a_2d_grid_half_a_millimetre_apart():
    cal = ProbeCalibration(0.5, PretravelModel(0.015), SPHERE, PAD_Z + 0.5 - 0.015)
    touches = plan_nozzle_calibration(cal, O_NOMINAL, NOZZLE_D, DIAMETER, PAD_NOMINAL, pad_touches=144,
                                      side_touches=1, clearance_mm=0.3, pad_z_mm=PAD_Z)
    probe = np.array([t.start_mm for t in touches if t.kind == "pad"])
    nozzle = np.array([t.start_mm for t in touches if t.kind == "nozzle_pad"])
    assert len(probe) == len(nozzle) == 144 and pad_grid(144) == (12, 12)
    assert len({(round(x, 6), round(y, 6)) for x, y, _ in probe}) == 144       # 144 distinct spots
    assert np.ptp(probe[:, 0]) == pytest.approx(5.5) and np.ptp(probe[:, 1]) == pytest.approx(5.5)
    assert probe[:, :2].mean(axis=0) == pytest.approx(PAD_NOMINAL[:2])
    # the same spots for both tools (the pad's flatness cancels), starting clearance_mm above the given pad
    assert sorted(map(tuple, (nozzle[:, :2] + O_NOMINAL[:2]).round(6))) == sorted(map(tuple, probe[:, :2].round(6)))
    assert probe[:, 2] == pytest.approx(PAD_Z + 0.5 + 0.3) and nozzle[:, 2] == pytest.approx(PAD_Z + 0.3 - O_NOMINAL[2])
    # consecutive spots of a block are neighbours (serpentine): every hop is 0.5 mm
    steps = np.linalg.norm(np.diff(probe[:72, :2], axis=0), axis=1)
    assert steps == pytest.approx(0.5)


def test_offsets_are_recovered_exactly_without_noise():
    probe = TrueProbe(r=0.5, p0=0.015, a=0.002)
    cal = qualified(probe)
    touches = plan_nozzle_calibration(cal, O_NOMINAL, NOZZLE_D, DIAMETER, PAD_NOMINAL)
    nozzle = fit_nozzle_offset(1, touches, nozzle_readings(touches, probe), cal, NOZZLE_D, DIAMETER)
    assert nozzle.offset_mm == pytest.approx(O_TRUE, abs=1e-6)
    assert nozzle.tool == 1 and nozzle.touches == 14 and nozzle.outer_diameter_mm == NOZZLE_D
    assert NozzleCalibration.from_dict(nozzle.to_dict()) == nozzle


@pytest.mark.parametrize("seed", [11, 12, 13, 14])
def test_offsets_are_recovered_within_a_micron_with_half_a_micron_noise(seed):
    rng = np.random.default_rng(seed)
    probe = TrueProbe(r=0.5, p0=0.015, scatter=0.0005, noise=0.0005)
    cal = qualified(probe, rng)
    touches = plan_nozzle_calibration(cal, O_NOMINAL, NOZZLE_D, DIAMETER, PAD_NOMINAL, pad_touches=8,
                                     side_touches=3)
    nozzle = fit_nozzle_offset(2, touches, nozzle_readings(touches, probe, noise=0.0005, rng=rng), cal, NOZZLE_D,
                               DIAMETER)
    error = np.subtract(nozzle.offset_mm, O_TRUE)
    assert np.abs(error).max() < 0.001
    assert all(0 < s < 0.001 for s in nozzle.std_mm)
    assert np.all(np.abs(error) < 4 * np.array(nozzle.std_mm))


def test_radius_and_diameter_cancel_in_xy():
    """A wrong sphere diameter or body diameter in the fit changes nothing in XY (only the sanity bound)."""
    probe = TrueProbe(r=0.5, p0=0.015)
    cal = qualified(probe)
    touches = plan_nozzle_calibration(cal, O_NOMINAL, NOZZLE_D, DIAMETER, PAD_NOMINAL)
    readings = nozzle_readings(touches, probe)
    a = fit_nozzle_offset(1, touches, readings, cal, NOZZLE_D, DIAMETER)
    b = fit_nozzle_offset(1, touches, readings, cal, 1.2, DIAMETER + 1)
    assert a.offset_mm == pytest.approx(b.offset_mm, abs=1e-12)


def test_a_missing_side_and_an_absurd_pair_are_refused():
    probe = TrueProbe()
    cal = qualified(probe)
    touches = plan_nozzle_calibration(cal, O_NOMINAL, NOZZLE_D, DIAMETER, PAD_NOMINAL)
    readings = nozzle_readings(touches, probe)
    keep = [i for i, t in enumerate(touches) if not (t.kind == "nozzle_side" and t.direction[1] > 0.5)]
    with pytest.raises(CalibrationError) as err:
        fit_nozzle_offset(1, [touches[i] for i in keep], readings[keep], cal, NOZZLE_D, DIAMETER)
    assert err.value.value == ["-y"]
    with pytest.raises(CalibrationError) as err:      # a 3 mm sphere: the pair is 4 mm too far apart
        fit_nozzle_offset(1, touches, readings, cal, NOZZLE_D, 3.0)
    assert err.value.field.startswith("readings[")
