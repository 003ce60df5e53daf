"""The mock LK-G sensor against the mock machine's truth: protocol, optics, timing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hardware.errors import FirmwareError
from hardware.height_sensor import HeightSensor, SensorRejected, lkg
from hardware.height_sensor.mock import unregister_sensor
from hardware.machine import Machine
from hardware.mock import MockPad, MockSphere

PAD_TOP = 5.0


@pytest.fixture
def rig(make_world):
    """``rig(sensor_options, **world) -> (machine, sensor, world)`` on a fresh world."""
    made = []

    def make(options: str = "", rate_hz: float = 2000.0, **world_kwargs):
        url, world = make_world(**world_kwargs)
        name = url.removeprefix("mock://")
        machine = Machine(url)
        machine.connect()
        machine.home()
        sensor = HeightSensor(f"lkg://{name}?rate_hz={rate_hz}&{options}".rstrip("&"), rate_hz=rate_hz)
        sensor.connect()
        made.append((name, sensor))
        return machine, sensor, world

    yield make
    for name, sensor in made:
        sensor.close()
        unregister_sensor(name)


def test_value_format_round_trips_and_marks_what_has_no_value():
    assert lkg.format_value(1.2345, 5.0) == "+01.2345"
    assert lkg.format_value(-0.012, 5.0) == "-00.0120"
    assert lkg.format_value(7.0, 5.0) == "+FFFFFFF" and lkg.format_value(-7.0, 5.0) == "-FFFFFFF"
    assert lkg.format_value(None, 5.0) == "XXXXXXXX"
    for v in (0.0, 4.9999, -3.1416, 0.0001):
        assert lkg.parse_value(lkg.format_value(v, 5.0)) == pytest.approx(v, abs=5e-5)
    assert lkg.parse_value("XXXXXXXX") is None and lkg.parse_value("-FFFFFFF") is None
    with pytest.raises(lkg.LkgFormatError):
        lkg.parse_value("1.2345")


def test_a_still_reading_is_the_pad_height_above_the_sensor_zero(rig):
    machine, sensor, _ = rig("offset=10,-4,-6&noise_mm=0&scale_error=0.01", pad=MockPad((60, 40, PAD_TOP), 20))
    machine.move(50.0, 44.0, 12.0)  # spot at (60, 40): the pad's centre; zero at z = 6
    assert sensor.measure() == pytest.approx((PAD_TOP - 6.0) * 1.01, abs=1e-4)
    machine.move(50.0, 44.0, 20.0)  # zero at 14: 9 mm below it is over the +-5 mm range
    assert sensor.measure() is None


def test_storage_stamps_each_cycle_and_sees_an_edge_late_by_the_time_offset(rig):
    tau_s, v = 0.0037, 20.0  # the sensor's offset; scan speed mm/s
    machine, sensor, _ = rig(f"offset=0,0,-5&noise_mm=0&time_offset_ms={tau_s * 1000}&spot_mm=0",
                             rate_hz=5000.0, pad=MockPad((50, 50, PAD_TOP), 20))
    edges = []
    for start, end in ((30.0, 50.0), (70.0, 50.0)):
        machine.move(start, 50.0, 5.0)
        sensor.start_storage()
        machine.stream([f"G1 X{end} F{v * 60}", "M400"])
        values, valid = sensor.stop_storage()
        assert len(values) == int(round(abs(end - start) / v * 5000)) + 1 and valid.all()
        t = sensor.stamps(len(values))
        x = start + np.sign(end - start) * np.minimum(v * t, abs(end - start))  # the commanded carriage
        k = int(np.argmax(values > PAD_TOP / 2))  # the first sample on the pad
        edges.append(x[k])
    # the value at stamp t was exposed at t - tau: the carriage is already v * tau further on
    assert edges[0] == pytest.approx(40.0 + v * tau_s, abs=v / 5000 + 1e-9)
    assert edges[1] == pytest.approx(60.0 - v * tau_s, abs=v / 5000 + 1e-9)


def test_no_value_on_steep_slopes_dark_spots_and_a_status_error_in_communication_mode(rig):
    sphere = MockSphere((100.0, 100.0, 10.0), 20.0)
    machine, sensor, _ = rig("offset=0,0,-20&noise_mm=0&acceptance_deg=30&dark=100,100,0.5", sphere=sphere)
    machine.move(100.0, 100.0, 40.0)
    assert sensor.measure() is None                  # the dark spot on the sphere's pole
    machine.move(102.0, 100.0, 40.0)                 # tilt asin(0.2) = 11.5 deg
    assert sensor.measure() == pytest.approx(10 + math.sqrt(100 - 4) - 20, abs=2e-4)
    machine.move(106.0, 100.0, 38.0)                 # tilt asin(0.6) = 36.9 deg > 30
    assert sensor.measure() is None
    sensor.command("Q0")
    with pytest.raises(SensorRejected, match="status error"):
        sensor.measure()
    sensor.command("R0")
    with pytest.raises(FirmwareError, match="command error"):
        sensor.command("ZZ")


def test_noise_and_slope_bias_follow_their_settings(rig):
    machine, sensor, _ = rig("offset=0,0,-5&noise_mm=0.002&slope_bias_mm=0.01&seed=3&spot_mm=0&acceptance_deg=40",
                             rate_hz=1000.0, sphere=MockSphere((0.0, 0.0, 0.0), 20.0))
    machine.move(6.0, 0.0, 13.0)  # tilt asin(0.6): tan^2 = 0.5625
    sensor.start_storage()
    machine.stream(["G4 S1", "M400"])  # one second still
    values, valid = sensor.stop_storage()
    assert valid.all() and len(values) == 1001
    assert np.mean(values) == pytest.approx(8.0 + 0.01 * 0.5625 - 8.0, abs=3 * 0.002 / math.sqrt(1001))
    assert np.std(values) == pytest.approx(0.002, rel=0.1)
