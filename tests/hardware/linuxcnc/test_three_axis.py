"""A three-axis compensated print program on LinuxCNC's simulator (hardware/linuxcnc/sim/xyz.ini).

The program (``compensate_trace`` for the ``linuxcnc`` dialect with the profile's
dispense codes ``M64 P0`` / ``M65 P0``) is run on the controller; joint positions are
sampled while the dispense output is on (program lines between the on and off codes)
and compared with the compensated tip polyline, which sits the standoff above the real
surface.  The dispense output itself is read from HAL (``motion.digital-out-00``).
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from app.compensation.standoff import CompensationParams, compensate_trace
from hardware.linuxcnc.hal_command import hal_command
from hardware.protocol import validate_program
from tests.compensation.test_standoff import full_rec
from tests.hardware.linuxcnc.conftest import PROFILE
from tests.hardware.linuxcnc.sampling import LineSampler

STANDOFF = 0.1


def _digital_out(sim) -> bool:  # type: ignore[no-untyped-def]
    """motion.digital-out-00 read straight from the simulator's HAL (``halcmd getp``)."""
    done = subprocess.run(hal_command(["halcmd", "getp", "motion.digital-out-00"], sim.hal_env), capture_output=True,
                          text=True, timeout=10, env=sim.hal_env)
    value = {"TRUE": True, "FALSE": False}.get(done.stdout.strip())
    assert value is not None, f"halcmd getp: {done.stdout!r} {done.stderr!r}"
    return value


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
    on, off = commands.index(PROFILE.dispense_on) + 1, commands.index(PROFILE.dispense_off) + 1
    machine = lcnc_xyz.machine(PROFILE)
    machine.connect()
    machine.home()
    link = machine.link
    outputs: list[bool] = []

    def check_output(n: int) -> None:
        if n % 200 == 1:
            value = _digital_out(lcnc_xyz)  # halcmd: slow under load, so the line is checked again
            if sampler.line() < off:  # read before the dispense-off line ran
                outputs.append(value)

    with LineSampler(link, on + 1, off, 3, each=check_output) as sampler:
        report = machine.stream(program)
    after = _digital_out(lcnc_xyz)
    machine.disconnect()
    assert report.executed == report.total == len(commands)
    samples = np.asarray(sampler.samples)
    # the host polls linuxcncrsh for them, up to every 0.5 ms: hundreds on a quiet box, a few
    # dozen at load 30 (44 seen); what is asserted holds for each one
    assert len(samples) >= 30
    error = _distance_to_polyline(samples, path.points)
    gap = samples[:, 2] - rec.real(samples[:, :2])
    print(f"\n3-axis compensated: {len(samples)} samples, max distance to the program path "
          f"{error.max() * 1000:.2f} um, standoff {gap.min():.4f}..{gap.max():.4f} mm; "
          f"dispense output samples {outputs}, after the program {after}")
    assert error.max() < 0.002  # the G64 P0.001 blending bound plus rounding
    assert gap == pytest.approx(STANDOFF, abs=path.max_chord_error_mm + 0.002)
    assert outputs and all(outputs) and after is False
