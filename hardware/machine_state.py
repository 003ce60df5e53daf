"""The state every machine backend keeps, declared once: :class:`MachineState`.

One object per machine holds its open link, the state machine (disconnected | idle | busy |
printing | paused | error), the one-operation-at-a-time rule (an operation claims the
machine: ``MachineBusy`` while another holds it, ``MachineStateError`` when it is
disconnected or in error, and releases it with the state it leaves), the cancel and
emergency-stop flags and the running program's progress.  The backends and their
collaborators receive it in their constructors; none reaches into another's attributes.

The checks both backends make before an operation (``require``, ``require_stoppable``,
``connected``) and the status both report (``base_status``) live here too.
"""

from __future__ import annotations

import threading
from typing import Any, Generic, Protocol, TypeVar

from .errors import MachineBusy, MachineStateError
from .machine_types import Identity

__all__ = ["MachineState", "StateReadout", "base_status", "connected"]


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
    ``link``, ``state``, ``link_lost``, ``estopped``, ``progress``."""

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


def base_status(machine_state: MachineState[Any], dialect: str, url: str, identity: Identity | None,
                program: dict[str, Any] | None) -> dict[str, Any]:
    """What every backend's ``status()`` reports: state, dialect, url, firmware and
    ``program``; a backend adds its link's counters and what else it knows."""
    return {"state": machine_state.state, "dialect": dialect, "url": url,
            "firmware": identity.firmware if identity is not None else None, "program": program}
