"""A stop stops the process too, on the serial dialects: after an emergency stop mid-line
and a reconnect the mock firmware's dispenser is off (its own state, not the host's belief),
and a travel-only program deposits nothing (the mock's deposition log)."""

from __future__ import annotations

import threading
import time

import pytest

from hardware.errors import HardwareError
from hardware.machine import Machine
from hardware.machine_types import MachineProfile

DISPENSE = {"marlin": ("M106", "M107"), "grbl": ("M3", "M5")}


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
    assert world.stats.stops == 1 and not world.firmware.dispensing   # the firmware's own state
    machine.connect()
    assert not world.firmware.dispensing
    deposited = len(world.deposition_log)
    report = machine.stream(["G90", "G0 Z25", "G0 X5 Y5 Z25"])    # travel only
    assert report.executed == report.total == 3
    assert len(world.deposition_log) == deposited and not world.firmware.dispensing
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
