"""The three-axis simulator's laser height sensor (sim/sensor.hal) against the simulated block.

The HAL component computes the reading from the block under the spot with the mock
sensor's optics; the controller samples it with the joints in the servo thread and
``HalScan`` reads the rows with halsampler.  The truth: :meth:`SimBlock.top_z` at the spot
(carriage + the sensor's offset), the sensor's zero at carriage z + its z offset.
"""

from __future__ import annotations

import numpy as np
import pytest

from hardware.linuxcnc import SimBlock, SimSensor
from hardware.linuxcnc.hal_scan import HalScan

OFFSET = (30.0, 5.0, -10.0)
BLOCK = SimBlock(40.0, 30.0, 2.0, 0.02, dx=10.0, dy=-5.0, dz=0.1, rz_deg=1.0)


def _scan(machine, sim, start, end, speed_mm_s):
    """One straight pass (carriage from ``start`` to ``end``, mm) sampled through HAL."""
    machine.move(z=start[2])
    machine.move(x=start[0], y=start[1])
    scan = HalScan(sim.hal_env)
    scan.start()
    try:
        machine.stream(["G90", f"G1 X{end[0]:.4f} Y{end[1]:.4f} Z{end[2]:.4f} F{speed_mm_s * 60:.1f}"])
    finally:
        samples = scan.stop()
    return samples


def _truth(block, xyz):
    """(surface under the spot, the sensor's zero) for carriage positions (n, 3)."""
    spot = xyz[:, :2] + OFFSET[:2]
    return np.array([block.top_z(x, y) for x, y in spot]), xyz[:, 2] + OFFSET[2]


def test_a_scan_pass_samples_the_block_under_the_spot_every_servo_period(lcnc_xyz, machine):
    lcnc_xyz.set_surface(BLOCK)
    lcnc_xyz.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0005))
    # the spot crosses the block along y = 8 (machine), from the bed onto the top and off again
    samples = _scan(machine, lcnc_xyz, (-25.0, 3.0, 12.0), (25.0, 3.0, 12.5), 20.0)
    assert samples.period_s == pytest.approx(0.001)
    steps = np.diff(samples.t) / 0.001  # values exposed at servo periods, in order; most in every one
    assert np.allclose(steps, np.round(steps)) and np.round(steps).min() >= 1 and np.median(np.round(steps)) == 1
    assert samples.t[-1] > 50.0 / 20.0  # the whole pass (2.5 s at 20 mm/s) and the rest
    # the joints' feedback: the motors, within the homing latch's repeatability of the commands
    assert samples.xyz[0] == pytest.approx([-25.0, 3.0, 12.0], abs=0.01)
    assert samples.xyz[-1] == pytest.approx([25.0, 3.0, 12.5], abs=0.01)
    surface, zero = _truth(BLOCK, samples.xyz)
    error = zero + samples.reading - surface
    spot = samples.xyz[:, :2] + OFFSET[:2]
    u, v = np.array([BLOCK.part_uv(x, y) for x, y in spot]).T
    near_edge = (np.abs(u) < 0.05) | (np.abs(u - BLOCK.length_mm) < 0.05)  # the spot straddles the edge
    ok = np.isfinite(error) & ~near_edge
    assert np.isfinite(samples.reading[~near_edge]).all()  # no dropout on a 1.1 degree top or the bed
    on_top = ok & (u > 0) & (u < BLOCK.length_mm)
    assert on_top.sum() > 100 and (ok & ~on_top).sum() > 50  # fewer values than periods on a loaded host
    for where in (on_top, ok & ~on_top):
        assert abs(np.median(error[where])) < 0.0005
        assert np.abs(error[where]).max() < 0.004
    # each value is paired with the joints at its exposure, however late it reached the sampler:
    # what is left is the sensor's noise (0.5 um) and its 0.1 um resolution
    assert 0.0003 < np.std(error[on_top]) < 0.0008


def test_steep_slopes_drop_out_and_noiseless_values_are_exact(lcnc_xyz, machine):
    steep = SimBlock(6.0, 30.0, 1.0, 0.6, dx=10.0, dy=-5.0, dz=0.1)  # a 31 degree top
    lcnc_xyz.set_surface(steep)
    lcnc_xyz.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0, resolution_mm=0.0001, acceptance_deg=25.0))
    samples = _scan(machine, lcnc_xyz, (-25.0, 3.0, 12.0), (-10.0, 3.0, 12.0), 20.0)
    spot_u = samples.xyz[:, 0] + OFFSET[0] - steep.dx
    top = (spot_u > 0.05) & (spot_u < steep.length_mm - 0.05)
    bed = (spot_u < -0.05) | (spot_u > steep.length_mm + 0.05)
    # 0.3 s over the top: ~300 values on a quiet host, 32-44 seen at load 18-25 (the component
    # shares the cores); each one must be a drop-out, beyond the acceptance angle
    assert top.sum() >= 20 and np.isnan(samples.reading[top]).all()
    assert np.isfinite(samples.reading[bed]).all()
    surface, zero = _truth(steep, samples.xyz)
    assert np.abs(zero + samples.reading - surface)[bed] == pytest.approx(0.0, abs=6e-5)  # no noise: exact
    # a wider acceptance sees the same top: every value exact at its exposure (resolution 0.1 um),
    # the carriage moving down over it
    lcnc_xyz.set_sensor(SimSensor(offset_mm=OFFSET, noise_mm=0.0, acceptance_deg=40.0))
    samples = _scan(machine, lcnc_xyz, (-17.0, 3.0, 11.5), (-17.0, 3.0, 11.0), 2.0)
    surface, zero = _truth(steep, samples.xyz)
    assert np.isfinite(samples.reading).all() and np.ptp(samples.xyz[:, 2]) > 0.49
    assert zero + samples.reading == pytest.approx(surface, abs=6e-5)
