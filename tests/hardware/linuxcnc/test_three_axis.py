"""A three-axis compensated print program on LinuxCNC's simulator (hardware/linuxcnc/sim/xyz.ini).

The program (``compensate_trace`` for the ``linuxcnc`` dialect with the profile's
dispense codes ``M64 P0`` / ``M65 P0``) is run on the controller; joint positions are
sampled at the controller (HAL, ``HalWatch``: ``joint.N.pos-fb`` with the dispense output
``motion.digital-out-00``, every 0.5 ms, independent of linuxcncrsh and of the box's load
on our own process) while the dispense output is on, and compared with the compensated tip
polyline, which sits the standoff above the real surface.
"""

from __future__ import annotations

import numpy as np
import pytest

from app.compensation.standoff import CompensationParams, compensate_trace
from hardware.protocol import validate_program
from tests.compensation.test_standoff import full_rec
from tests.hardware.linuxcnc.conftest import PROFILE

STANDOFF = 0.1


def _distance_to_polyline(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.clip(np.einsum("kij,ij->ki", p[:, None, :] - a[None], ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2).min(axis=1)


def test_compensated_print_program_runs_on_the_path(lcnc_xyz):
    rec = full_rec()
    path = compensate_trace(rec, CompensationParams(
        standoff_mm=STANDOFF, feed_mm_min=1200.0, dialect="linuxcnc", dispense_on=PROFILE.dispense_on,
        dispense_off=PROFILE.dispense_off))
    program = path.program.splitlines()
    assert program[-1] == "M2" and "M106" not in path.program
    commands = validate_program(program)
    machine = lcnc_xyz.machine(PROFILE)
    machine.connect()
    machine.home()
    with lcnc_xyz.watch(["joint.0.pos-fb", "joint.1.pos-fb", "joint.2.pos-fb", "motion.digital-out-00"]) as watch:
        report = machine.stream(program)
    machine.disconnect()
    assert report.executed == report.total == len(commands)
    assert commands.index(PROFILE.dispense_on) < commands.index(PROFILE.dispense_off)
    # every sample while the dispense output was on, less the first and last 0.2 mm of the
    # trace (the path's ends, where the controller stops)
    on = np.array([v[:3] for _, v in watch.samples if v[3] == 1])
    assert len(on) > 100, len(on)
    ends = on[[0, -1]]
    inner = np.linalg.norm(on[:, None, :2] - ends[None, :, :2], axis=2).min(axis=1) > 0.2
    samples = on[inner]
    assert len(samples) > 100
    after = watch.samples[-1][1][3]
    error = _distance_to_polyline(samples, path.points)
    gap = samples[:, 2] - rec.real(samples[:, :2])
    print(f"\n3-axis compensated: {len(samples)} HAL samples with the dispense output on, max distance to the "
          f"program path {error.max() * 1000:.2f} um, standoff {gap.min():.4f}..{gap.max():.4f} mm; dispense "
          f"output after the program {after}")
    assert error.max() < 0.002  # the G64 P0.001 blending bound plus rounding
    assert gap == pytest.approx(STANDOFF, abs=path.max_chord_error_mm + 0.002)
    assert after == 0  # the output is off once the program ended
