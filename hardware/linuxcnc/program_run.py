"""Write a program file and run it on LinuxCNC, following it (``LinuxCNCMachine.stream``).

The controller reads the file itself; the host opens it (``set mode auto``, ``set open``,
``set run``) and polls ``program_line``, then ``program_status``, then ``error`` every
``poll_s``.  A cancel request becomes ``set abort``; an emergency stop or a controller
error ends the run with ``FirmwareError``; a lost session raises ``LinkError`` (the caller
records what is known executed).
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..errors import FirmwareError, LinkError
from ..machine_state import connected
from ..resume import modal_preamble
from .task_watch import TaskWatch

if TYPE_CHECKING:
    from .machine import LinuxCNCMachine

__all__ = ["resume_preamble", "run_program", "write_program"]

# IDLE right after "set run" with the program line at 0 means "not started yet" ("set open"
# resets the line to 0; a program that ran, however quickly, leaves its last line): waited for
# up to this long, on a loaded host the task may take seconds to start it
_START_GRACE_S = 10.0
# an end is taken when this many status reads in a row say so: under twice the stress load a
# stream was seen to return while the controller still ran its program (the next MDI refused
# in AUTO), so one read is not trusted for an end; it costs one poll
_END_READS = 2
_PROGRAM_ENDS = ("M2", "M30")


def resume_preamble(machine: LinuxCNCMachine, commands: list[str], start_line: int) -> list[str]:
    """Resuming mid-program: the commands that restore units, work offsets, motion mode,
    feed, the start point, distance mode and the dispenser as the skipped commands left
    them (``hardware.resume.modal_preamble``), written at the top of the program file;
    kept as the machine's ``last_preamble``."""
    machine.last_preamble = []
    if start_line == 0:
        return []
    p = machine.profile
    machine.last_preamble = modal_preamble(commands, start_line, dispense_on=p.dispense_on,
                                           dispense_off=p.dispense_off, clearance_z=p.clearance_z)
    return list(machine.last_preamble)


def write_program(directory: str, commands: list[str]) -> str:
    """Write ``commands`` (plus ``M2`` when they have no program end) to
    ``<directory>/conforma-<sha>.ngc`` atomically; returns the absolute path."""
    if commands[-1].split()[0].upper() not in _PROGRAM_ENDS:
        commands = [*commands, "M2"]
    text = "\n".join(commands) + "\n"
    digest = hashlib.sha256(text.encode()).hexdigest()[:20]
    os.makedirs(directory, exist_ok=True)
    path = os.path.join(directory, f"conforma-{digest}.ngc")
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w", encoding="utf-8") as handle:
        handle.write(text)
    os.replace(tmp, path)
    return path


def run_program(machine: LinuxCNCMachine, path: str, start_line: int, total: int,
                on_progress: Callable[[int, int], None] | None, skip: int = 0) -> tuple[int, bool]:
    """Run ``path`` (its first ``skip`` lines are a modal preamble, then line n is command
    ``start_line + n - 1 - skip``); returns (executed, cancelled).  The machine's progress
    is kept current."""
    st = machine.machine_state
    link = connected(st.link)
    count = total - start_line
    link.set("mode", "auto")
    link.pop_error()
    link.set("open", path)
    link.set("run")
    started = time.monotonic()
    watch = TaskWatch(link, "the program")
    seen_running = False
    ended_reads = 0
    executed = start_line
    while True:
        if st.estopped:
            raise FirmwareError("emergency stop: the program was stopped", command="estop")
        if st.cancel_requested:
            link.set("abort")
            return executed, True
        # the line before the status: a status read IDLE just before the program starts and a
        # line read just after (line 1) would pass for a program that ran and ended; read the
        # other way, a line > 0 before an IDLE status means it started, and has ended since
        line = int(float(link.get("program_line") or 0))
        status = link.get("program_status").upper()
        error = link.pop_error()
        if error is not None:
            link.set("abort")
            raise FirmwareError(f"LinuxCNC stopped the program at line {line}: {error}",
                                command=f"line {line}")
        if status in ("RUNNING", "PAUSED"):
            seen_running, ended_reads = True, 0
            if line > skip:
                executed = max(executed, start_line + min(line - 1 - skip, count))
        elif seen_running or line > 0 or time.monotonic() - started > _START_GRACE_S:
            ended_reads += 1
            if ended_reads >= _END_READS:
                executed = total
        if st.current in ("printing", "paused"):
            st.current = "paused" if status == "PAUSED" else "printing"
        st.progress = (executed, total)
        if on_progress is not None:
            on_progress(executed, total)
        if executed == total:
            return executed, False
        if time.monotonic() - started > machine.motion_timeout_s:
            raise LinkError("the program did not finish in time", field="program")
        watch.check()
        time.sleep(machine.poll_s)
