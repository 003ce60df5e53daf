"""After an emergency stop not one more byte of the program is written.

The host-side wire transcript (every ``write`` to the port, in order) must end with the
stop byte, on the mock grbl and the mock Marlin, whatever the stream was doing when the
operator pressed STOP; and the firmware executes nothing after it."""

from __future__ import annotations

import threading
import time

import pytest

from hardware.errors import FirmwareError, HardwareError
from hardware.machine import Machine

STOP_BYTES = {"marlin": b"M112\n", "grbl": b"\x18"}


def _record_writes(machine: Machine) -> list[bytes]:
    """Wrap the open port's ``write`` so every byte the host sends is logged in order."""
    wire: list[bytes] = []
    port = machine.link.port
    write = port.write

    def recording(data: bytes) -> int:
        wire.append(bytes(data))
        return write(data)

    port.write = recording
    return wire


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
@pytest.mark.parametrize("stop_after", [1, 17, 150])
def test_the_wire_ends_at_the_stop_byte(make_world, dialect, stop_after):
    url, world = make_world(dialect=dialect, time_scale=0.02)
    machine = Machine(url, dialect, boot_wait_s=0.0, poke_s=0.05)
    machine.connect()
    wire = _record_writes(machine)
    program = [f"G1 X{i % 50}.0 Y{(7 * i) % 40}.0 F6000" for i in range(400)]
    errors: list[Exception] = []
    reached = threading.Event()

    def run() -> None:
        try:
            machine.stream(program, on_progress=lambda done, _total: done >= stop_after and reached.set())
        except HardwareError as exc:
            errors.append(exc)

    streamer = threading.Thread(target=run)
    streamer.start()
    assert reached.wait(20), "the program never got going"
    stops_before = world.stats.stops
    machine.emergency_stop()
    # what ran before the stop byte reached the firmware is the mock's truth (it takes the
    # stop on arrival, after the wire's transit): nothing may run after it
    deadline = time.monotonic() + 5
    while world.stats.stops == stops_before and time.monotonic() < deadline:
        time.sleep(0.005)
    assert world.stats.stops == stops_before + 1
    executed_at_stop = world.stats.executed_at_stop
    assert 0 < executed_at_stop < len(program)
    streamer.join(10)
    assert not streamer.is_alive()
    assert errors and isinstance(errors[0], FirmwareError)
    assert wire[-1] == STOP_BYTES[dialect], wire[-3:]
    assert wire.count(STOP_BYTES[dialect]) == 1
    time.sleep(0.2)  # anything still on its way would be executed by now
    assert world.executed_count == executed_at_stop
    assert machine.state == "error"
    with pytest.raises(HardwareError):
        machine.link.send("G1 X1")  # the link stays terminal: reconnect to go on
    assert wire[-1] == STOP_BYTES[dialect]
    machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_stop_while_idle_still_sends_the_firmware_stop(make_world, dialect):
    url, world = make_world(dialect=dialect)
    machine = Machine(url, dialect, boot_wait_s=0.0)
    machine.connect()
    wire = _record_writes(machine)
    machine.emergency_stop()
    assert wire == [STOP_BYTES[dialect]]
    assert machine.state == "error"
    machine.connect()  # reopening clears the stop
    assert machine.state == "idle"
    machine.disconnect()
