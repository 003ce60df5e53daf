"""A stop stops the process too, on the serial dialects: after an emergency stop mid-line
and a reconnect the mock firmware's dispenser is off (its own state, not the host's belief),
and a travel-only program deposits nothing (the mock's deposition log).  A plain connect, a
disconnect and the start of each program leave every output off (the profile's
``safe_off``), a resumed program turns the dispenser back on only where it was on, and a
grbl that boots locked in Alarm (its reset switched its outputs off) still connects."""

from __future__ import annotations

import threading
import time

import pytest

from hardware.dialects import DIALECTS
from hardware.errors import HardwareError
from hardware.machine import Machine
from hardware.machine_types import MachineProfile

DISPENSE = {name: rules.dispense for name, rules in DIALECTS.items()}  # the mock's dispenser outputs


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_stop_mid_line_and_reconnect_leave_the_dispenser_off(make_world, dialect):
    on, off = DISPENSE[dialect]
    url, world = make_world(dialect=dialect, time_scale=0.05)
    machine = Machine(url, dialect, MachineProfile(dispense_on=on, dispense_off=off), boot_wait_s=0.0, poke_s=0.05)
    machine.connect()
    program = ["G90", "G1 Z1 F600", on, *(f"G1 X{10 + 10 * (i % 2)} Y{i} F600" for i in range(40)), off]
    errors: list[Exception] = []
    dispensing = threading.Event()

    def run() -> None:
        try:
            machine.stream(program, on_progress=lambda done, _total: done >= 6 and dispensing.set())
        except HardwareError as exc:
            errors.append(exc)

    streamer = threading.Thread(target=run)
    streamer.start()
    try:
        assert dispensing.wait(20), "the program never got going"
        deadline = time.monotonic() + 5
        while not world.firmware.dispensing and time.monotonic() < deadline:
            time.sleep(0.005)
        assert world.firmware.dispensing and world.deposition_log    # mid-line, depositing
        machine.stop()
    finally:
        streamer.join(20)
    assert errors and machine.state == "error"
    deadline = time.monotonic() + 5
    while world.stats.stops == 0 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert world.stats.stops == 1
    # the firmware's own state: Marlin's kill() leaves a fan output (M106) as it was until the
    # board resets; grbl's mc_reset() switched spindle and coolant off
    assert world.firmware.dispensing is (dialect == "marlin")
    outputs = machine.status()["outputs"]
    assert outputs["safe_off"] == "emergency stop" and outputs["sent"] is False
    assert (on.split()[0] in outputs["why"]) is (dialect == "marlin")   # what the firmware's own stop leaves on
    deposited = len(world.deposition_log)
    machine.connect()
    assert not world.firmware.dispensing and len(world.deposition_log) == deposited
    seen: list[bool] = []
    report = machine.stream(["G90", "G0 Z25", "G0 X5 Y5 Z25"],    # travel only
                            on_progress=lambda *_: seen.append(world.firmware.dispensing))
    assert report.executed == report.total == 3
    assert seen == [False] * 3 and not world.firmware.dispensing
    assert len(world.deposition_log) == deposited
    machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_a_lost_link_and_a_reconnect_leave_the_dispenser_off(make_world, dialect):
    from hardware.mock import FaultConfig

    on, off = DISPENSE[dialect]
    url, world = make_world(dialect=dialect, faults=FaultConfig(disconnect_at_line=6))
    machine = Machine(url, dialect, MachineProfile(dispense_on=on, dispense_off=off), boot_wait_s=0.0, poke_s=0.05)
    machine.connect()
    with pytest.raises(HardwareError):
        machine.stream(["G90", "G1 Z1 F600", on, *(f"G1 X{i} Y{i} F600" for i in range(20)), off])
    machine.connect()
    deposited = len(world.deposition_log)
    machine.stream(["G90", "G0 Z25", "G0 X5 Y5 Z25"])    # travel only
    assert len(world.deposition_log) == deposited and not world.firmware.dispensing
    machine.disconnect()


def _machine(make_world, dialect: str, **world):  # type: ignore[no-untyped-def]
    on, off = DISPENSE[dialect]
    url, mock = make_world(dialect=dialect, **world)
    profile = MachineProfile(dispense_on=on, dispense_off=off, outputs_off=("M9",) if dialect == "grbl" else ())
    return Machine(url, dialect, profile, boot_wait_s=0.0, poke_s=0.05), mock


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_a_connect_switches_off_what_another_host_left_on(make_world, dialect):
    first, world = _machine(make_world, dialect)
    first.connect()
    first.send(DISPENSE[dialect][0])
    assert world.firmware.dispensing
    first.link.close()            # the host went away without a disconnect: the output stays on
    if dialect == "marlin":
        assert world.firmware.dispensing
    second = Machine(first.url, dialect, first.profile, boot_wait_s=0.0, poke_s=0.05)
    second.connect()
    assert not world.firmware.dispensing
    assert world.transcript.commands[-len(first.profile.safe_off):] == list(first.profile.safe_off)
    assert second.status()["outputs"] == {"safe_off": "connect", "sent": True, "why": None}
    second.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_a_disconnect_switches_the_outputs_off(make_world, dialect):
    machine, world = _machine(make_world, dialect)
    machine.connect()
    machine.send(DISPENSE[dialect][0])
    assert world.firmware.dispensing
    before = len(world.transcript.commands)
    machine.disconnect()
    assert not world.firmware.dispensing
    assert world.transcript.commands[before:] == list(machine.profile.safe_off)


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_a_new_program_starts_with_every_output_off(make_world, dialect):
    on, off = DISPENSE[dialect]
    machine, world = _machine(make_world, dialect)
    machine.connect()
    machine.send(on)                   # left on from the console
    before = len(world.transcript.commands)
    seen: list[bool] = []
    program = ["G90", "G0 Z25", "G0 X5 Y5 Z25"]
    machine.stream(program, on_progress=lambda *_: seen.append(world.firmware.dispensing))
    assert seen == [False] * 3 and not world.deposition_log
    assert world.transcript.commands[before:] == [*machine.profile.safe_off, *program]
    assert machine.last_preamble == list(machine.profile.safe_off)
    # a program that turns the dispenser on has it on where it asks, and only there
    machine.stream(["G90", "G1 Z1 F600", on, "G1 X10 F600", off, "G0 Z25"])
    assert [tuple(round(v, 3) for v in d.end) for d in world.deposition_log] == [(10.0, 5.0, 1.0)]
    machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
@pytest.mark.parametrize("start, dispensing", [(3, False), (6, True)])
def test_a_resumed_program_starts_from_safe_off_and_the_dispenser_as_the_program_had_it(
        make_world, dialect, start, dispensing):
    on, off = DISPENSE[dialect]
    machine, world = _machine(make_world, dialect)
    machine.connect()
    machine.send(on)
    program = ["G90", "G1 Z1 F600", "G1 X1 F600", "G1 X2 F600", on, "G1 X3 F600", "G1 X4 F600", off, "G0 Z25"]
    before = len(world.transcript.commands)
    machine.stream(program, start_line=start)
    sent = world.transcript.commands[before:]
    safe = list(machine.profile.safe_off)
    assert sent[:len(safe)] == safe and machine.last_preamble[:len(safe)] == safe
    assert (on in machine.last_preamble) is dispensing
    assert sent == [*machine.last_preamble, *program[start:]]
    # deposited: the program's moves with its dispenser on, none of the replay's travel
    assert [round(d.end[0], 3) for d in world.deposition_log] == ([4.0] if dispensing else [3.0, 4.0])
    machine.disconnect()


def test_a_grbl_booting_in_alarm_connects_with_its_outputs_off_by_its_reset(make_world):
    machine, world = _machine(make_world, "grbl", homing=True)
    machine.connect()                  # G-code is error:9 in Alarm: safe_off is not sent, not failed
    assert machine.status()["controller"] == "Alarm" and not world.firmware.dispensing
    outputs = machine.status()["outputs"]
    assert outputs["safe_off"] == "connect" and outputs["sent"] is False and "Alarm" in outputs["why"]
    assert not [c for c in world.transcript.commands if c in machine.profile.safe_off]
    machine.unlock()
    machine.disconnect()               # unlocked and idle: the disconnect sends safe_off
    assert world.transcript.commands[-len(machine.profile.safe_off):] == list(machine.profile.safe_off)
