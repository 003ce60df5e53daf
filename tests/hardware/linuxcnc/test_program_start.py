"""A program that the controller starts late: ``run_program`` must not take the IDLE it reads
right after ``set run`` for the program's end.  A scripted linuxcncrsh plays a task that starts
the program 1.5 s after ``set run`` (a loaded host), runs it for 0.5 s and ends it; no
simulator needed."""

from __future__ import annotations

import time

from hardware.linuxcnc.program_run import run_program
from tests.helpers.scripted_rsh import ScriptedRsh, printing_machine

START_S, RUN_S, LINES = 1.5, 0.5, 3


class _LateTask:
    """linuxcncrsh whose program starts ``START_S`` after ``set run``: IDLE at line 0 until
    then (``set open`` reset it), RUNNING through lines 1..LINES for ``RUN_S``, then IDLE at
    its last line."""

    def __init__(self) -> None:
        self.run_at: float | None = None
        self.reported_running = False

    def _state(self) -> tuple[str, int]:
        if self.run_at is None:
            return "IDLE", 0
        t = time.monotonic() - self.run_at - START_S
        if t < 0:
            return "IDLE", 0
        if t < RUN_S:
            self.reported_running = True
            return "RUNNING", 1 + min(int(t / RUN_S * LINES), LINES - 1)
        return "IDLE", LINES

    def __call__(self, line: str, connection: int) -> str | None:
        if line == "set run":
            self.run_at = time.monotonic()
        if line == "get program_status":
            return f"PROGRAM_STATUS {self._state()[0]}"
        if line == "get program_line":
            return f"PROGRAM_LINE {self._state()[1]}"
        if line == "get error":
            return "ERROR OK"
        return None


def test_a_program_started_late_is_waited_for_and_not_reported_finished_before_it_ran():
    task = _LateTask()
    server = ScriptedRsh(task)
    machine = printing_machine(server)
    seen: list[tuple[int, int]] = []
    started = time.monotonic()
    executed, cancelled = run_program(machine, "/tmp/program.ngc", 0, LINES, lambda e, t: seen.append((e, t)))
    assert (executed, cancelled) == (LINES, False)
    assert task.reported_running  # it returned after the program ran, not before
    assert time.monotonic() - started >= START_S + RUN_S
    assert any(0 < e < LINES for e, _ in seen)  # its progress was seen on the way
    server.close()


class _StartsBetweenReads(_LateTask):
    """linuxcncrsh whose program starts right after it answered the first ``get
    program_status`` (IDLE): a status and a line read around that moment straddle the start."""

    def __call__(self, line: str, connection: int) -> str | None:
        reply = super().__call__(line, connection)
        if line == "get program_status" and self.run_at is not None and self.run_at > time.monotonic() - START_S:
            self.run_at = time.monotonic() - START_S  # it starts now
        return reply


def _run(task: _LateTask) -> tuple[int, bool, float]:
    """(executed, cancelled, seconds until it returned) of ``run_program`` against ``task``."""
    server = ScriptedRsh(task)
    started = time.monotonic()
    executed, cancelled = run_program(printing_machine(server), "/tmp/program.ngc", 0, LINES, None)
    server.close()
    return executed, cancelled, time.monotonic() - started


def test_a_program_that_starts_between_the_status_and_the_line_read_is_not_taken_for_finished():
    executed, cancelled, seconds = _run(_StartsBetweenReads())
    assert (executed, cancelled) == (LINES, False)
    assert seconds >= RUN_S  # it returned after the program ran, not at its start


class _GlitchedStatus(_LateTask):
    """linuxcncrsh whose status reads IDLE once while the program runs (read mid-update on a
    loaded host): the program itself runs on."""

    def __init__(self) -> None:
        super().__init__()
        self.glitched = False

    def __call__(self, line: str, connection: int) -> str | None:
        reply = super().__call__(line, connection)
        if line == "get program_status" and reply == "PROGRAM_STATUS RUNNING" and not self.glitched:
            self.glitched = True
            return "PROGRAM_STATUS IDLE"
        return reply


def test_one_read_of_an_ended_program_while_it_runs_does_not_end_the_stream():
    task = _GlitchedStatus()
    executed, cancelled, seconds = _run(task)
    assert task.glitched and (executed, cancelled) == (LINES, False)
    assert seconds >= START_S + RUN_S  # after the program's true end
