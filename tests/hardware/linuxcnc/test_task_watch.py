"""A controller whose task died is found within seconds, not after the motion timeout: its
status freezes (homing reads "not homed", a program RUNNING), so the machine's waits ask the
task for a no-op command every few seconds (hardware/linuxcnc/task_watch.py).  A scripted
linuxcncrsh plays the frozen controller; the real simulator's task is killed mid-program."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from hardware.errors import LinkError
from hardware.linuxcnc import SimController, task_watch
from hardware.linuxcnc.machine import LinuxCNCMachine
from hardware.linuxcnc.rsh import RshSession
from hardware.linuxcnc.stop_session import ESTOP_CONFIRM_S, ESTOP_REPLY_S, ESTOP_TRIES
from hardware.linuxcnc.task_watch import TaskWatch
from tests.hardware.linuxcnc.conftest import PROFILE, wait_until
from tests.helpers.real_components import missing
from tests.helpers.scripted_rsh import ScriptedRsh

LOST = ""  # a reply line linuxcncrsh never sent


class _FrozenController:
    """linuxcncrsh over a task that died: ``get`` answers the last status (joints not homed),
    a ``set`` the task must receive is never answered (``alive`` False)."""

    def __init__(self, alive: bool = False, refuse: bool = False) -> None:
        self.alive, self.refuse = alive, refuse

    def __call__(self, line: str, connection: int) -> str | None:
        if line == "get optional_stop":
            return "OPTIONAL_STOP 1"
        if line == "get joint_homed":
            return "JOINT_HOMED NO NO NO NO NO NO"
        if line == "get mode":
            return "MODE MANUAL"
        if line.startswith("set optional_stop"):
            return "SET OPTIONAL_STOP NAK" if self.refuse else None if self.alive else LOST
        return None


def _watch(controller: _FrozenController, clock: list[float]) -> tuple[ScriptedRsh, TaskWatch]:
    server = ScriptedRsh(controller)
    session = RshSession.open("127.0.0.1", server.port, "pw", timeout_s=0.5)
    return server, TaskWatch(session, "homing", every_s=5.0, clock=lambda: clock[0])


def test_a_wait_asks_the_task_for_a_no_op_every_few_seconds():
    clock = [0.0]
    server, watch = _watch(_FrozenController(alive=True), clock)
    for now in (0.0, 4.9, 5.0, 6.0, 9.9, 10.0):
        clock[0] = now
        watch.check()
    # the switch set to the value the controller reports, once per 5 s of waiting
    assert server.lines("get optional_stop") == ["get optional_stop"] * 2
    assert server.lines("set optional_stop") == ["set optional_stop 1"] * 2


def test_a_task_that_takes_no_command_ends_the_wait_and_says_what_to_do():
    clock = [0.0]
    _, watch = _watch(_FrozenController(alive=False), clock)
    clock[0] = 5.0
    started = time.monotonic()
    with pytest.raises(LinkError) as caught:
        watch.check()
    assert time.monotonic() - started < 2.0  # the session's timeout (0.5 s), not the motion's hour
    assert caught.value.field == "controller"
    message = caught.value.message
    assert "waiting for homing" in message and "frozen" in message and "emergency stop" in message


def test_a_refused_no_op_tells_nothing_about_the_task():
    clock = [0.0]
    server, watch = _watch(_FrozenController(refuse=True), clock)
    clock[0] = 5.0
    watch.check()  # e.g. an emergency stop during the wait: the machine is not on
    assert server.lines("set optional_stop") == ["set optional_stop 1"]


def test_homing_on_a_controller_whose_task_died_fails_in_seconds(monkeypatch):
    monkeypatch.setattr(task_watch, "TASK_CHECK_S", 0.5)
    server = ScriptedRsh(_FrozenController(alive=False))
    machine = LinuxCNCMachine(f"linuxcnc://127.0.0.1:{server.port}?joints=3", PROFILE, connect_pw="pw",
                              enable_pw="pw", timeout_s=1.0)
    machine.machine_state.link = RshSession.open("127.0.0.1", server.port, "pw", timeout_s=1.0)
    machine.machine_state.current = "idle"
    started = time.monotonic()
    with pytest.raises(LinkError, match="waiting for homing"):
        machine.home()  # the motion timeout is an hour
    assert time.monotonic() - started < 0.5 + 1.0 + 2.0
    assert machine.state == "error"


def test_a_program_whose_controller_task_dies_fails_in_seconds_and_says_so(_one_simulator, monkeypatch):
    """The real controller: its task process killed while a 20 s move runs.  linuxcncrsh keeps
    answering from the frozen status (RUNNING); the stream ends within the check's period and
    the session's timeout, in ``error``, telling the operator to use the machine's e-stop."""
    _one_simulator.close()  # a simulator of this test's own (its task is killed)
    monkeypatch.setattr(task_watch, "TASK_CHECK_S", 1.0)
    with SimController("xyz") as sim:
        machine = sim.machine(PROFILE, timeout_s=5.0)
        machine.connect()
        machine.home()
        outcome: list[BaseException | None] = []
        polling = threading.Event()  # the stream's wait has begun (its ``set run`` was answered)

        def stream() -> None:
            try:
                machine.stream(["G1 X40 F120"], on_progress=lambda *_: polling.set())  # 20 s
                outcome.append(None)
            except BaseException as exc:  # noqa: BLE001 - handed to the test's thread
                outcome.append(exc)

        runner = threading.Thread(target=stream, daemon=True)
        observer = sim.session()
        runner.start()
        assert wait_until(lambda: polling.is_set() and observer.get("program_status") == "RUNNING", timeout_s=30.0)
        observer.close()
        tasks = sim.task_pids()
        if not tasks:
            missing("the simulator's task process", "no milltask in the simulator's IPC namespace")
        for pid in tasks:
            os.kill(pid, signal.SIGKILL)
        killed = time.monotonic()
        # the check's period, the session's timeout, then the stop session's aborts (each unanswered)
        bound = 1.0 + 5.0 + ESTOP_TRIES * (ESTOP_REPLY_S + ESTOP_CONFIRM_S) + 3.0
        runner.join(timeout=bound + 10.0)
        elapsed = time.monotonic() - killed
        assert not runner.is_alive(), "the stream still waits on a frozen status"
        assert isinstance(outcome[0], LinkError) and "task" in outcome[0].message, outcome
        assert elapsed < bound, elapsed
        assert machine.state == "error"
        told = [entry.text for entry in machine.console.since().entries]
        assert told[-1].startswith(f"the abort was not confirmed after {ESTOP_TRIES} tries"), told[-3:]
