"""The state every machine backend keeps, declared once: :class:`MachineState`.

One object per machine holds its open link, the state machine (disconnected | idle | busy |
printing | paused | error), the one-operation-at-a-time rule (an operation claims the
machine: ``MachineBusy`` while another holds it, ``MachineStateError`` when it is
disconnected or in error, and releases it with the state it leaves), the cancel and
emergency-stop flags, the running program's progress and, once a program is lost, what is
known of it (:class:`InterruptedProgram`, one record type for every backend).  The backends
and their collaborators receive it in their constructors; none reaches into another's
attributes.

The checks both backends make before an operation (``require``, ``require_stoppable``,
``connected``), the status both report (``base_status``, ``program_status``) and
the part of a resume an interrupted program's record tells alone
(``InterruptedProgram.known_resume``) live here too.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from .errors import MachineBusy, MachineStateError
from .machine_types import Identity, ReportEvidence

__all__ = ["InterruptedProgram", "MachineState", "StateReadout", "base_status", "connected"]


class _Health(Protocol):
    @property
    def healthy(self) -> bool: ...


L = TypeVar("L", bound=_Health)
_Link = TypeVar("_Link")


def connected(link: _Link | None) -> _Link:
    """``link``, an operation's open link; ``MachineStateError`` while disconnected (None)."""
    if link is None:
        raise MachineStateError("machine is not connected", field="state", value="disconnected")
    return link


@dataclass
class InterruptedProgram:
    """What a backend knows of a program it lost (a dropped link; on the serial link also a
    rejected line), recorded at that moment and kept in ``MachineState.interrupted`` until
    the next program starts:

    * ``total`` commands; commands ``[0, acked_index)`` known processed (serial: acknowledged;
      LinuxCNC: before the file line its ``program_line`` reported running);
    * ``acked_line_no``: the firmware's line number of the last acknowledged command (Marlin
      numbers the lines it receives; None where no line is numbered on the wire);
    * ``inflight``: (line number, command index) of the commands sent but not acknowledged;
    * ``reset``: the controller restarted (its queue and line numbering are gone);
    * ``moved_index``: commands ``[0, moved_index)`` known to have *moved* (a serial ``ok``
      only means planned; LinuxCNC's ``program_line`` is the line in motion); None: not bounded;
    * ``report``: the last real position the controller reported while streaming
      (``hardware.reports``; serial only);
    * ``program_file``: the file the controller itself ran (LinuxCNC: the modal preamble,
      then the commands from the start line); None when the host sent the lines one by one."""

    total: int
    acked_index: int
    acked_line_no: int | None
    inflight: list[tuple[int | None, int]]
    reset: bool
    moved_index: int | None = None
    report: ReportEvidence | None = None
    program_file: str | None = None

    @classmethod
    def adopted(cls, total: int, acked_index: int, acked_line_no: int | None) -> InterruptedProgram:
        """What an earlier process recorded (a job's ``program_state``), taken over by a new
        one: commands ``[0, acked_index)`` processed, the last of them numbered
        ``acked_line_no`` and the later ones numbered on from it (the controller is asked which
        of them it took); without a line number the controller's queue counts as gone."""
        inflight: list[tuple[int | None, int]] = [] if acked_line_no is None else \
            [(acked_line_no + 1 + k, acked_index + k) for k in range(total - acked_index)]
        return cls(int(total), int(acked_index), acked_line_no, inflight, reset=acked_line_no is None)

    def known_resume(self, resets_on_connect: bool = False) -> int | None:
        """The first command a resume sends when this record alone tells it: after a reset
        (``resets_on_connect``: the controller restarts whenever the host connects) the
        first command not known to have moved; with nothing in flight the first not known
        processed; None while commands in flight wait for the controller's line numbers."""
        if resets_on_connect or self.reset:
            return self.moved_index if self.moved_index is not None else self.acked_index
        return None if self.inflight else self.acked_index


class MachineState(Generic[L]):
    """A machine's link, state, claim, flags and progress (see the module docstring).

    ``error_when_lost``: the states reported as ``error`` once the link is unhealthy (the
    serial stream notices a lost link itself and leaves ``error`` when it does)."""

    def __init__(self, error_when_lost: tuple[str, ...] = ("idle", "busy")) -> None:
        self.link: L | None = None
        self.current = "disconnected"  # what the last operation set
        self.hold = threading.Lock()  # held by the one running operation
        self.cancel_requested = False
        self.estopped = False  # after an emergency stop, until the next connect
        self.progress: tuple[int, int] | None = None  # (executed, total) of the running program
        self.interrupted: InterruptedProgram | None = None  # the program a failure stopped, until the next
        self._error_when_lost = error_when_lost

    @property
    def live_link(self) -> L:
        """The open link; ``MachineStateError`` while disconnected."""
        return connected(self.link)

    @property
    def state(self) -> str:
        """disconnected | idle | busy | printing | paused | error."""
        if self.link is None:
            return "disconnected"
        if not self.link.healthy and self.current in self._error_when_lost:
            return "error"
        return self.current

    @property
    def link_lost(self) -> bool:
        """True when the link failed under a connected machine (not after an emergency
        stop): reconnecting and resuming is safe."""
        return self.link is not None and not self.link.healthy and not self.estopped

    def fail_state(self) -> str:
        """The state an operation that failed leaves: ``error`` after an emergency stop or
        on a lost link (nothing more is sent until the next connect), else ``idle``."""
        return "error" if self.estopped or self.link is None or not self.link.healthy else "idle"

    def claim(self, state: str) -> None:
        """Hold the machine for one operation, which runs in ``state``."""
        if self.link is None:
            raise MachineStateError("machine is not connected", field="state", value="disconnected")
        if not self.hold.acquire(blocking=False):
            raise MachineBusy(f"machine is {self.current}", field="state", value=self.current)
        if self.state == "error":
            self.hold.release()
            raise MachineStateError("machine is in error state: reconnect first", field="state",
                                    value="error")
        self.current = state

    def release(self, state: str = "idle") -> None:
        """End the operation holding the machine, leaving it in ``state``."""
        self.current = state
        self.hold.release()

    def connecting(self) -> None:
        """A connect begins: busy, no emergency stop in force."""
        self.current = "busy"
        self.estopped = False

    def require(self, states: tuple[str, ...], what: str) -> None:
        """``MachineStateError`` naming ``what`` cannot be done unless the machine is in one
        of ``states`` (pause, resume and cancel act on a program)."""
        if self.current not in states:
            raise MachineStateError(f"{what} while {self.state}", field="state", value=self.state)

    def require_stoppable(self) -> None:
        """The service's stop: ``MachineStateError`` while idle or disconnected (nothing is
        sent, the machine stays as it is)."""
        state = self.state
        if state not in ("printing", "paused", "busy"):
            raise MachineStateError(f"nothing to stop: machine is {state}", field="state", value=state)

    def stopping(self) -> L:
        """An emergency stop begins: cancel whatever runs and refuse everything until the next
        connect; returns the link to stop over (``MachineStateError`` while disconnected:
        there is nothing to stop).  It claims nothing: a stop never waits for an operation."""
        link = connected(self.link)
        self.cancel_requested = True
        self.estopped = True
        return link

    def program_started(self, start_line: int, total: int) -> None:
        """A program's run begins (the machine claimed): no cancel pending, the interrupted
        program it may resume is forgotten, progress at ``start_line`` of ``total``."""
        self.cancel_requested = False
        self.interrupted = None
        self.progress = (start_line, total)

    def program_status(self, resets_on_connect: bool = False, located: int | None = None) -> dict[str, Any] | None:
        """The program on this machine: while it runs ``running_program``; once interrupted
        ``{"state": "interrupted", "line", "total", "resume_line"}``: commands known
        processed, of the total, and the first command a resume sends: ``located`` when the
        backend located it, else what the record tells alone (``known_resume``; None: the
        controller is asked).  None when there is neither."""
        running = self.running_program()
        if running is not None:
            return running
        gap = self.interrupted
        if gap is None:
            return None
        resume = located if located is not None else gap.known_resume(resets_on_connect)
        return {"state": "interrupted", "line": gap.acked_index, "total": gap.total, "resume_line": resume}

    def running_program(self) -> dict[str, Any] | None:
        """``{"state": "printing"|"paused", "line", "total"}`` while a program runs
        (commands acknowledged so far, of the total), else None."""
        state = self.state
        if self.progress is None or state not in ("printing", "paused"):
            return None
        executed, total = self.progress
        return {"state": state, "line": executed, "total": total}


class StateReadout(Generic[L]):
    """What every backend reports of its ``MachineState`` (built with it, read only here):
    ``link``, ``state``, ``link_lost``, ``estopped``, ``progress``, ``interrupted_program``."""

    def __init__(self, machine_state: MachineState[L]) -> None:
        self.machine_state = machine_state

    @property
    def link(self) -> L | None:
        """The open link (None while disconnected)."""
        return self.machine_state.link

    @property
    def state(self) -> str:
        """disconnected | idle | busy | printing | paused | error."""
        return self.machine_state.state

    @property
    def link_lost(self) -> bool:
        """True when the link failed under a connected machine (not after an emergency
        stop): reconnecting and resuming is safe."""
        return self.machine_state.link_lost

    @property
    def estopped(self) -> bool:
        """True after an emergency stop, until the next ``connect``."""
        return self.machine_state.estopped

    @property
    def progress(self) -> tuple[int, int] | None:
        """(executed, total) commands of the running (or last) program."""
        return self.machine_state.progress

    @property
    def interrupted_program(self) -> InterruptedProgram | None:
        """What is known of the program a failure stopped (None: none waits for a resume)."""
        return self.machine_state.interrupted


def base_status(machine_state: MachineState[Any], dialect: str, url: str, identity: Identity | None,
                program: dict[str, Any] | None) -> dict[str, Any]:
    """What every backend's ``status()`` reports: state, dialect, url, firmware and
    ``program``; a backend adds its link's counters and what else it knows."""
    return {"state": machine_state.state, "dialect": dialect, "url": url,
            "firmware": identity.firmware if identity is not None else None, "program": program}
