"""Elapsed time and time left of the program a machine runs, for the operator's display.

    clock = ProgramClock()
    clock.start(start_line=0)          # the stream begins
    clock.pause(); clock.resume()      # a held program's time does not count as running
    clock.elapsed_s()                  # wall seconds since the start, pauses included
    clock.eta_s(executed=120, total=1000)

The time left is the *rate so far*, weighted by a plan when one was given: with
``expect(cumulative_s)`` (the host's estimate of each command's duration, e.g.
:func:`app.gcode.estimator.command_times`, summed) before the stream starts, time left =
running seconds x (planned seconds left / planned seconds done): the estimate scaled by how
fast the machine really goes.  Without a plan (or one that does not fit the program) it is
running seconds per executed line times the lines left, which assumes every line takes as
long as the average one run so far.  ``None`` until ``MIN_LINES`` lines ran or
``MIN_RUNNING_S`` passed, when the rate means little.  Monotonic time, so a clock change on
the host does not move it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

MIN_LINES = 20
MIN_RUNNING_S = 2.0


class ProgramClock:
    """See the module docstring.  Not thread-safe on its own: the machine's stream and its
    pause/resume calls write it, the API only reads it (floats, read whole)."""

    def __init__(self) -> None:
        self.started_at: float | None = None  # Unix time of the start (for display)
        self._t0 = 0.0  # monotonic start
        self._paused_since: float | None = None
        self._paused_s = 0.0
        self._start_line = 0
        self._pending: Sequence[float] | None = None  # the plan for the next start
        self._plan: Sequence[float] | None = None  # (total + 1,) cumulative planned seconds

    def expect(self, cumulative_s: Sequence[float]) -> None:
        """The next program's plan: ``cumulative_s[i]`` planned seconds before command ``i``
        (length commands + 1).  Used by the next ``start`` only."""
        self._pending = cumulative_s

    def start(self, start_line: int = 0) -> None:
        """A program starts streaming at ``start_line`` (a resumed program counts only the
        lines it runs itself)."""
        self.started_at = time.time()
        self._t0 = time.monotonic()
        self._paused_since = None
        self._paused_s = 0.0
        self._start_line = start_line
        self._plan, self._pending = self._pending, None

    def pause(self) -> None:
        if self._paused_since is None:
            self._paused_since = time.monotonic()

    def resume(self) -> None:
        if self._paused_since is not None:
            self._paused_s += time.monotonic() - self._paused_since
            self._paused_since = None

    def elapsed_s(self) -> float | None:
        """Wall seconds since the start (``None`` before any program)."""
        return None if self.started_at is None else time.monotonic() - self._t0

    def running_s(self) -> float | None:
        """``elapsed_s`` minus the time the program was held."""
        elapsed = self.elapsed_s()
        if elapsed is None:
            return None
        held = self._paused_s + (time.monotonic() - self._paused_since if self._paused_since is not None else 0.0)
        return max(0.0, elapsed - held)

    def eta_s(self, executed: int, total: int) -> float | None:
        """Seconds left at the line rate so far (see the module docstring)."""
        running = self.running_s()
        done = executed - self._start_line
        if running is None or done <= 0 or (done < MIN_LINES and running < MIN_RUNNING_S):
            return None
        plan = self._plan
        if plan is not None and len(plan) == total + 1:
            planned_done = plan[executed] - plan[self._start_line]
            if planned_done > 0:
                return running * max(0.0, plan[total] - plan[executed]) / planned_done
        return running / done * max(0, total - executed)
