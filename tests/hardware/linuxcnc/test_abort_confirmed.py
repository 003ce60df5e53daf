"""A program is aborted until the controller reports it idle, and a reply linuxcncrsh loses
costs a short wait, not the machine's timeout: on a lost command session or a failed command
the program must not run on unsupervised, and the caller (a stream ending in ``LinkError``)
must not hang.  A scripted server plays linuxcncrsh (no simulator needed); the abort at a real
controller is tested in ``test_machine.py``."""

from __future__ import annotations

import time

import pytest

from hardware.linuxcnc.stop_session import ESTOP_CONFIRM_S, ESTOP_REPLY_S, ESTOP_TRIES
from tests.helpers.scripted_rsh import ScriptedRsh, printing_machine

LOST = ""  # a reply line linuxcncrsh never sent (the session reads on past empty lines)


class _Controller:
    """linuxcncrsh running a program: ``set abort`` ends it (unless ``stuck``); the replies to
    the first ``lost`` lines that start with ``lose`` never arrive."""

    def __init__(self, lose: str = "", lost: int = 0, stuck: bool = False) -> None:
        self.lose, self.lost, self.stuck = lose, lost, stuck
        self.status = "RUNNING"

    def __call__(self, line: str, connection: int) -> str | None:
        if line == "set abort" and not self.stuck:
            self.status = "IDLE"
        if line == "get program_status":
            return f"PROGRAM_STATUS {self.status}"
        if self.lose and line.startswith(self.lose) and self.lost > 0:
            self.lost -= 1
            return LOST
        return None


def _disconnect_timed(machine) -> float:  # type: ignore[no-untyped-def]
    started = time.monotonic()
    machine.disconnect()
    return time.monotonic() - started


@pytest.mark.parametrize("lose", ["set abort", "set enable"])
def test_a_lost_reply_costs_the_short_wait_and_the_abort_is_confirmed(lose):
    controller = _Controller(lose=lose, lost=1)
    server = ScriptedRsh(controller)
    machine = printing_machine(server)  # timeout_s 5: a lost reply awaited that long would show
    elapsed = _disconnect_timed(machine)
    assert controller.status == "IDLE"
    assert elapsed < ESTOP_REPLY_S + 1.5, elapsed
    console = [entry.text for entry in machine.console.since().entries]
    assert console.count("set abort") == 2  # the try whose reply was lost, then the confirmed one
    assert console[-1] == "program_status IDLE: the program is aborted"
    assert machine.state == "disconnected"


def test_an_abort_the_controller_never_reports_is_told_and_bounded():
    controller = _Controller(stuck=True)
    server = ScriptedRsh(controller)
    machine = printing_machine(server)
    elapsed = _disconnect_timed(machine)
    assert len(server.lines("set abort")) == ESTOP_TRIES
    assert elapsed < ESTOP_TRIES * (ESTOP_CONFIRM_S + 0.5), elapsed
    last = machine.console.since().entries[-1]
    assert last.direction == "received" and last.text.startswith(f"the abort was not confirmed after {ESTOP_TRIES}")
    assert machine.state == "disconnected"
