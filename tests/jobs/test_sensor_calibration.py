"""The height sensor's calibration on the mock: time offset, offset and scale recovered.

The true values are drawn from a seeded generator (never used to tune anything); the mock
machine holds the pad and the datum sphere, the mock sensor the truth."""

from __future__ import annotations

import numpy as np
import pytest

from app.calibration.sensor import EdgePass, fit_scale_and_z, fit_time_offset
from app.jobs.sensor_runs import CalibrationSetup, SerialScanner, calibrate_sensor
from hardware.height_sensor import HeightSensor
from hardware.height_sensor.mock import unregister_sensor
from hardware.machine import Machine
from hardware.mock import MockPad, MockSphere, MockWorld, register_world, unregister_world

NOMINAL = (30.0, 5.0, -10.0)
PAD = (150.0, 10.0, 3.0)
SPHERE = (110.0, 12.0, 12.0)
DIAMETER = 25.4


def test_time_offset_from_synthetic_edges_is_exact():
    tau, v = 0.0021, 15.0
    x = np.linspace(-3, 3, 601)
    edge = np.where(x > 0.4, 2.0, -1.0)
    passes = [EdgePass(x + v * tau, edge, 1, v), EdgePass(x[::-1] - v * tau, edge[::-1], -1, v)]
    found, where, _ = fit_time_offset(passes, 0.5)
    assert found == pytest.approx(tau, abs=1e-6) and where == pytest.approx(0.4, abs=0.006)


def test_scale_and_z_from_a_line_of_still_readings():
    z = np.linspace(-2, 2, 9)
    r = 1.004 * (3.0 - z - (-10.0 + 12.0))
    k, oz, _ = fit_scale_and_z(z, r, 3.0)
    assert k == pytest.approx(1.004, rel=1e-9) and oz == pytest.approx(2.0, abs=1e-9)


@pytest.mark.parametrize("seed", [5, 6])
def test_the_mock_sensor_is_calibrated_within_1_ms_and_5_um(seed):
    rng = np.random.default_rng(seed)
    true_offset = np.asarray(NOMINAL) + rng.uniform(-0.2, 0.2, 3)
    tau = rng.uniform(0.5e-3, 5e-3)
    scale_error = rng.uniform(-0.01, 0.01)
    bias = rng.uniform(0.0, 0.004)
    name = f"cal{seed}"
    register_world(name, MockWorld(pad=MockPad(PAD, 20.0), sphere=MockSphere(SPHERE, DIAMETER)))
    machine = Machine(f"mock://{name}")
    machine.connect()
    machine.home()
    sensor = HeightSensor(f"lkg://{name}?offset={','.join(f'{v:.6f}' for v in true_offset)}&time_offset_ms="
                          f"{tau * 1000:.6f}&scale_error={scale_error:.6f}&slope_bias_mm={bias:.6f}"
                          f"&noise_mm=0.0005&rate_hz=2000&seed={seed}", rate_hz=2000)
    sensor.connect()
    try:
        setup = CalibrationSetup(PAD, 20.0, SPHERE, DIAMETER / 2, NOMINAL, 5.0, travel_z=40.0)
        cal, report = calibrate_sensor(machine, SerialScanner(machine, sensor), setup)
    finally:
        sensor.close()
        unregister_sensor(name)
        unregister_world(name)
    assert abs(cal.time_offset_s - tau) < 1e-3
    assert np.abs(np.asarray(cal.offset_mm) - true_offset).max() < 0.005
    assert cal.scale == pytest.approx(1 + scale_error, abs=5e-4)
    assert cal.slope_bias_mm == pytest.approx(bias, abs=1e-3)
    print(seed, (cal.time_offset_s - tau) * 1e3, (np.asarray(cal.offset_mm) - true_offset) * 1e3,
          cal.scale - 1 - scale_error, cal.slope_bias_mm - bias, report["sphere"]["rms_mm"])
