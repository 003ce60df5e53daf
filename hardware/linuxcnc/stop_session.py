"""The LinuxCNC backend's second linuxcncrsh session: used only to stop.

It takes control (``set enable``) right before it speaks, so a stop is never queued behind the
command session's operation (a ``set wait done`` that waits for motion).  An emergency stop is
sent until ``get estop`` reports it: linuxcncrsh (2.9) parses every session's line with one
shared ``strtok``, so a line can be read with the polling session's words and answered for, or
acted on as, something else (:mod:`hardware.linuxcnc.rsh`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..console_log import ConsoleLog
from ..errors import HardwareError, LinkError
from .rsh import RshRejected, RshSession

__all__ = ["ESTOP_CONFIRM_S", "ESTOP_REPLY_S", "ESTOP_TRIES", "StopSession"]

ESTOP_TRIES = 3
ESTOP_REPLY_S = 1.0  # linuxcncrsh answers a set once the controller took it (0.1-0.2 s)
ESTOP_CONFIRM_S = 0.5  # how long the controller's status may lag the ACK


class StopSession:
    """The stop session of one machine: ``open_session()`` connects (hello, echo off, verbose
    on), ``enable_pw`` takes control; a session that died is reopened on the next stop."""

    def __init__(self, open_session: Callable[[], RshSession], enable_pw: str) -> None:
        self._open_session = open_session
        self._enable_pw = enable_pw
        self.session: RshSession | None = None

    def open(self) -> None:
        """Connect now (at the machine's connect), so a stop finds its session ready."""
        self.session = self._open_session()

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
        self.session = None

    def _enabled(self, reply_s: float | None = None) -> RshSession:
        """The session, reopened if it died, after ``set enable`` (its reply awaited ``reply_s``,
        default the session's own timeout)."""
        session = self.session
        if session is None or not session.healthy:
            session = self.session = self._open_session()
        session.enable(self._enable_pw, timeout_s=reply_s)
        return session

    def estop(self, console: ConsoleLog) -> None:
        """``set estop on`` until the controller reports it, up to ``ESTOP_TRIES`` times (each
        try recorded in ``console``); ``LinkError`` when it never does."""
        failure: HardwareError | None = None
        for _ in range(ESTOP_TRIES):
            console.record("sent", "set estop on")
            try:
                if self._estop_once():
                    return
            except (LinkError, RshRejected) as exc:
                failure = exc
        raise LinkError(f"LinuxCNC did not report the emergency stop sent {ESTOP_TRIES} times"
                        + (f": {failure}" if failure else ""), field="port")

    def _estop_once(self) -> bool:
        """One ``set estop on``; True once ``get estop`` reports it within ``ESTOP_CONFIRM_S``."""
        session = self._enabled()
        session.set("estop", "on", timeout_s=ESTOP_REPLY_S)
        return _reported(session, "estop", "ON")

    def abort(self, console: ConsoleLog) -> bool:
        """``set abort`` until ``get program_status`` reports IDLE, up to ``ESTOP_TRIES`` times,
        each reply awaited ``ESTOP_REPLY_S`` (a reply linuxcncrsh lost costs that, not the
        machine's timeout; the session is then reopened).  Called when the command session is
        lost or a command failed: the program must not run on unsupervised.  Every try and the
        outcome are recorded in ``console``; True once the controller reported IDLE."""
        failure: HardwareError | None = None
        for _ in range(ESTOP_TRIES):
            console.record("sent", "set abort")
            try:
                if self._abort_once():
                    console.record("received", "program_status IDLE: the program is aborted")
                    return True
            except HardwareError as exc:
                failure = exc
        console.record("received", f"the abort was not confirmed after {ESTOP_TRIES} tries"
                       + (f": {failure}" if failure else ""))
        return False

    def _abort_once(self) -> bool:
        """One ``set abort``; True once ``get program_status`` reports IDLE within
        ``ESTOP_CONFIRM_S``."""
        session = self._enabled(ESTOP_REPLY_S)
        session.set("abort", timeout_s=ESTOP_REPLY_S)
        return _reported(session, "program_status", "IDLE")


def _reported(session: RshSession, name: str, value: str) -> bool:
    """True once ``get name`` reports ``value`` (case-insensitive) within ``ESTOP_CONFIRM_S``
    (the controller's status lags the ACK)."""
    deadline = time.monotonic() + ESTOP_CONFIRM_S
    while session.get(name).upper() != value:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True
