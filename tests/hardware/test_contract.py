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
TARGETS = ["mock-marlin", "mock-grbl", "real"]


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
    else:
        dialect = request.param.split("-")[1]
        name = f"contract-{dialect}"
        world = register_world(name, MockWorld(dialect=dialect))
        profile = MachineProfile() if dialect == "marlin" else MachineProfile("M3 S1000", "M5")
        machine = Machine(f"mock://{name}", dialect, profile, boot_quiet_s=0.01, poke_s=0.02)
        motion = True
    machine.connect()
    yield machine, world, motion
    machine.disconnect()
    if world is not None:
        unregister_world(f"contract-{machine.dialect}")


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
    if world is not None:
        assert world.transcript.digest() == commands_sha256(program)


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
    machine.home()
    assert machine.move(5.0, 5.0, 5.0) == pytest.approx((5.0, 5.0, 5.0), abs=0.01)
    point = machine.probe(5.0, 5.0, z_start=5.0, z_min=-2.0)
    assert (point.x, point.y) == pytest.approx((5.0, 5.0), abs=0.01)
