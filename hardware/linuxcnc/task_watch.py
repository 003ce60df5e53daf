"""Whether LinuxCNC's task still takes commands, asked during the machine's long waits.

linuxcncrsh answers ``get`` from the last status LinuxCNC's task published.  When the task
process dies or hangs, that status freezes where it was: homing reads "not homed", a running
program reads RUNNING at its line, and every wait that polls it would last until its
hour-long motion timeout while the operator sees "busy".  A ``set`` is answered only once the
task has received it, so during a wait the watch asks the task, every ``every_s``, to set its
optional-stop switch to the value it reports (a no-op that a GUI may send at any time, also
while a program runs).  An answer within the session's timeout shows the task alive; none
means the task has stopped: ``LinkError`` naming what the wait was for, that the status is
frozen and that only the machine's own emergency stop reaches motion already queued (the
session is then dead, as after any lost reply).

A NAK (the machine is not on: an emergency stop during the wait) tells nothing about the task
and is ignored; the wait's own checks see the stop.  The check reads the switch and writes the
same value back: a GUI that toggles it between the two would see its change undone.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..errors import LinkError
from .rsh import RshRejected, RshSession

TASK_CHECK_S = 5.0  # how often a long wait asks whether the task still takes commands


class TaskWatch:
    """The liveness check of one wait on ``session``: call :meth:`check` in its polling loop."""

    def __init__(self, session: RshSession, waiting_for: str, every_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.session = session
        self.waiting_for = waiting_for  # e.g. "homing", "the program": named in the error
        self.every_s = TASK_CHECK_S if every_s is None else every_s
        self._clock = clock
        self._last = clock()

    def check(self) -> None:
        """Ask the task for a command once ``every_s`` passed since the last answer;
        ``LinkError`` when it does not take it within the session's timeout."""
        if self._clock() - self._last < self.every_s:
            return
        value = self.session.get("optional_stop")
        try:
            self.session.set("optional_stop", value)
        except RshRejected:
            pass
        except LinkError as exc:
            raise LinkError(
                f"LinuxCNC's task took no command within {self.session.timeout_s:g} s while waiting for "
                f"{self.waiting_for}: the controller's task has stopped or hangs and the status it reports is "
                "frozen; motion already queued may still run and no stop reaches it through the task: use the "
                "machine's own emergency stop, then restart LinuxCNC and reconnect", field="controller") from exc
        self._last = self._clock()
