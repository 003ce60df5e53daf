"""One contract for every controller: the mock (Marlin and grbl personalities) and, when
``CONFORMA_TEST_PORT`` names a real port, real hardware.

Real-hardware settings: ``CONFORMA_TEST_PORT`` (e.g. ``/dev/ttyUSB0`` or
``socket://host:23``), ``CONFORMA_TEST_DIALECT`` (marlin|grbl, default marlin),
``CONFORMA_TEST_BAUD`` (default 115200).  Motion and probing run on real hardware only
with ``CONFORMA_TEST_MOTION=1`` (clear the work area first!)."""

from __future__ import annotations

import os

import pytest

from hardware.errors import FirmwareError, MachineStateError
from hardware.machine import Machine, MachineProfile
from hardware.mock import MockWorld, register_world, unregister_world
from hardware.protocol import commands_sha256

REAL_PORT = os.environ.get("CONFORMA_TEST_PORT")
# mock-grbl-homing: $22=1, grbl boots locked in Alarm until homed
TARGETS = ["mock-marlin", "mock-grbl", "mock-grbl-homing", "real"]


def ready(machine: Machine) -> None:
    """What an operator does after connecting: a grbl that boots locked (homing enabled)
    is homed; one in Alarm without homing is unlocked."""
    if machine.dialect == "grbl" and machine.last_controller_state() == "Alarm":
        if machine.can_home():
            machine.home()
        else:
            machine.unlock()


@pytest.fixture(params=TARGETS)
def target(request):
    """(machine, world or None, allows_motion)."""
    if request.param == "real":
        if not REAL_PORT:
            pytest.skip("CONFORMA_TEST_PORT is not set: real-hardware contract run skipped")
        dialect = os.environ.get("CONFORMA_TEST_DIALECT", "marlin")
        machine = Machine(REAL_PORT, dialect, baudrate=int(os.environ.get("CONFORMA_TEST_BAUD",
                                                                          "115200")))
        world, motion = None, os.environ.get("CONFORMA_TEST_MOTION") == "1"
        name = None
    else:
        dialect = request.param.split("-")[1]
        name = f"contract-{request.param}"
        world = register_world(name, MockWorld(dialect=dialect,
                                               homing=request.param.endswith("homing")))
        profile = MachineProfile() if dialect == "marlin" else MachineProfile("M8", "M9")
        machine = Machine(f"mock://{name}", dialect, profile, boot_quiet_s=0.01, poke_s=0.02)
        motion = True
    machine.connect()
    ready(machine)
    yield machine, world, motion
    machine.disconnect()
    if name is not None:
        unregister_world(name)


def test_environment_reaches_the_suite():
    """tests/conftest.py must leave CONFORMA_TEST_* alone (it once stripped them)."""
    import subprocess
    import sys

    env = {**os.environ, "CONFORMA_TEST_DIALECT": "grbl", "CONFORMA_TEST_MOTION": "1",
           "CONFORMA_TEST_BAUD": "250000", "CONFORMA_DATA_DIR": "/nonexistent"}
    code = ("import os, tests.conftest; print(os.environ.get('CONFORMA_TEST_DIALECT'), "
            "os.environ.get('CONFORMA_TEST_MOTION'), os.environ.get('CONFORMA_TEST_BAUD'), "
            "os.environ.get('CONFORMA_DATA_DIR'))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["grbl", "1", "250000", "None"]


def test_identifies_itself(target):
    machine, _, _ = target
    identity = machine.identity
    assert identity.dialect == machine.dialect and identity.firmware
    assert machine.state == "idle"


def test_reports_a_position(target):
    machine, _, _ = target
    position = machine.position()
    assert len(position) == 3 and all(isinstance(v, float) for v in position)


def test_streams_a_harmless_program_exactly(target):
    machine, world, _ = target
    program = ["G21", "G90", "; comment", "G4 P0", "G4 P0"]
    if world is not None:
        world.transcript.reset()
    report = machine.stream(program)
    assert report.executed == report.total == 4 and not report.cancelled
    if world is not None:   # every program starts with its outputs off (the profile's safe_off)
        assert world.transcript.digest() == commands_sha256([*machine.profile.safe_off, *program])


def test_rejected_command_is_a_firmware_error_or_echo(target):
    machine, _, _ = target
    if machine.dialect == "grbl":
        with pytest.raises(FirmwareError):
            machine.send("G5 X1")
    else:  # Marlin acknowledges unknown commands with an echo
        result = machine.send("G999")
        assert any("Unknown command" in line for line in result.reply_lines)
    assert machine.state == "idle"


def test_stop_while_idle_is_refused(target):
    machine, _, _ = target
    with pytest.raises(MachineStateError):
        machine.stop()
    assert machine.state == "idle"


def test_moves_and_probes(target):
    machine, _, motion = target
    if not motion:
        pytest.skip("motion on real hardware needs CONFORMA_TEST_MOTION=1")
    if machine.can_home():  # grbl with $22=0 cannot home: it starts unlocked at 0,0,0
        machine.home()
    assert machine.move(5.0, 5.0, 5.0) == pytest.approx((5.0, 5.0, 5.0), abs=0.01)
    point = machine.probe(5.0, 5.0, z_start=5.0, z_min=-2.0)
    assert (point.x, point.y) == pytest.approx((5.0, 5.0), abs=0.01)
