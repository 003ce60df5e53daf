"""What the serial machine's collaborators share: :class:`SerialCommands`.

``hardware.machine.Machine`` is composed of collaborators, each built with what it uses:
this object (the shared ``MachineState`` with the open link, the dialect's rules, the
profile, the answer timeout) and, where needed, another collaborator.  ``SerialCommands``
sends commands and reads positions over the open link, knows the controller's own state
(grbl Alarm, Hold, Door, Check lock motion) and claims the machine for motion.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

from .controller_state import ControllerState
from .dialects import Dialect
from .errors import ControllerLocked, FirmwareError, HardwareError, LinkError
from .events import PositionReport
from .link import CommandResult, Link
from .machine_state import MachineState
from .machine_types import MachineProfile

__all__ = ["JOG_POLL_S", "SerialCommands"]

JOG_POLL_S = 0.05  # how often a grbl that jogs is asked whether it still does, s


class SerialCommands:
    """Commands over the serial machine's open link (see the module docstring)."""

    def __init__(self, state: MachineState[Link], rules: Dialect, profile: MachineProfile, timeout_s: float) -> None:
        self.state = state
        self.rules = rules
        self.profile = profile
        self.timeout_s = timeout_s  # one command's answer, s (motion waits ten times this)

    @property
    def link(self) -> Link:
        """The open link; ``MachineStateError`` while disconnected."""
        return self.state.live_link

    def send(self, command: str, timeout_s: float | None = None) -> CommandResult:
        """One command, answered within ``timeout_s`` (default: a motion's wait)."""
        return self.link.send(command, self.timeout_s * 10 if timeout_s is None else timeout_s)

    def run(self, commands: Iterable[str]) -> list[CommandResult]:
        """Commands one after another, each waited for as a motion."""
        return [self.send(c) for c in commands]

    @property
    def wait_motion(self) -> str:
        """The command answered once every planned move has finished (M400 / G4 P0)."""
        return self.rules.wait_moves

    def position(self) -> tuple[float, float, float]:
        """Where the tool is (mm): grbl's status ``MPos``, Marlin's ``M114`` (planned)."""
        if self.rules.position_by_status:
            mpos = self.link.query_status().mpos or (0.0, 0.0, 0.0)
            return (mpos[0], mpos[1], mpos[2])
        report = self.send("M114", self.timeout_s).payload
        if not isinstance(report, PositionReport):
            raise FirmwareError("M114 returned no position", command="M114")
        return (report.axes.get("X", 0.0), report.axes.get("Y", 0.0), report.axes.get("Z", 0.0))

    @property
    def controller(self) -> ControllerState | None:
        """The firmware's own state with its reason (``hardware.session_types``), or None."""
        link = self.state.link
        return link.session.controller if link is not None else None

    def claim_motion(self, state: str, what: str, *, check: bool = True) -> None:
        """Claim the machine for an operation that moves it (``what``, for the message):
        ``ControllerLocked`` while the firmware refuses motion (see ``refuse_locked``)."""
        self.state.claim(state)
        if not check:
            return
        try:
            self.refuse_locked(what)
        except HardwareError:
            self.state.release()
            raise

    def refuse_locked(self, what: str) -> None:
        """``ControllerLocked`` naming the state, why and how to clear it, when the firmware
        refuses or holds motion now (grbl Alarm, Hold, Door, Check)."""
        known = self.controller
        if known is not None and known.locks_motion and self.rules.position_by_status:
            self.link.query_status()  # never refuse on a stale state: ask the firmware now
            known = self.controller
        if known is not None and known.locks_motion:
            raise ControllerLocked(locked_message(known, what), field="controller", value=known.state)

    def locked_reply(self, exc: FirmwareError, what: str) -> FirmwareError | ControllerLocked:
        """A command the firmware refused with its lock error (grbl ``error:9``) as the
        ``ControllerLocked`` it means; any other rejection unchanged."""
        code = self.rules.lock_error
        if code is None or exc.code != code:
            return exc
        known = self.controller or ControllerState("Alarm", str(exc))
        if not known.locks_motion:  # jogging: G-code waits for the jog to end
            return exc
        return ControllerLocked(locked_message(known, what), field="controller", value=known.state)

    def wait_not_jogging(self) -> None:
        """Poll grbl's status until it no longer jogs."""
        deadline = time.monotonic() + self.timeout_s * 10
        while self.link.query_status().state == "Jog":
            if time.monotonic() > deadline:
                raise LinkError("jog did not finish", field="timeout_s")
            time.sleep(JOG_POLL_S)


def locked_message(known: ControllerState, what: str) -> str:
    """Why ``what`` cannot run in the controller's state ``known``, and how to clear it."""
    why = f" ({known.reason})" if known.reason else ""
    return f"the controller is in {known.name}{why}: cannot {what}; {known.clear}"
