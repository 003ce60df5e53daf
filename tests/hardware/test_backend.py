"""Both machine backends offer what ``hardware.backend.Machine`` declares (mypy checks the
types where ``app.machines`` builds them; this checks every member exists at runtime)."""

from __future__ import annotations

from hardware.backend import Machine
from hardware.linuxcnc import LinuxCNCMachine
from hardware.machine import Machine as SerialMachine


def test_the_serial_machine_is_a_backend() -> None:
    machine = SerialMachine("mock://backend-check", "grbl")
    assert isinstance(machine, Machine)
    assert machine.state == "disconnected" and machine.link is None


def test_the_linuxcnc_machine_is_a_backend() -> None:
    machine = LinuxCNCMachine("linuxcnc://127.0.0.1:5007")  # nothing is opened before connect()
    assert isinstance(machine, Machine)
    assert machine.state == "disconnected" and machine.dialect == "linuxcnc"


def test_an_object_missing_a_member_is_not_one() -> None:
    class Partial:
        def connect(self) -> None: ...

    assert not isinstance(Partial(), Machine)
