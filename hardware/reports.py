"""Position reports during streaming (``PositionTracker``, owned by
``hardware.session.ReplySession``; pure: every method takes ``now``): where motion really is, asked for at a bounded
rate while the reader thread ticks the session, so that after a controller
reset the host knows how far the tool got (``hardware.resume.locate_by_report``).

* grbl: the real-time ``?`` status report (``MPos`` or ``WPos`` per ``$10``; ``WCO`` turns
  one into the other), answered on arrival whatever the planner holds.
* Marlin: ``S000`` (``REALTIME_REPORTING_COMMANDS``, which needs ``EMERGENCY_PARSER``):
  the emergency parser answers on arrival with the position *from the steppers*
  (``X:.. Y:.. Z:.. E:.. Count X:..``, then ``S_XYZ:<state>``); the line then goes on to
  the command queue, which acknowledges it with a plain ``ok`` in turn.  Its bytes sit in
  the firmware's receive buffer until then (a blocking command such as ``M400`` or a full
  planner keeps them there): they count in the window like a program line's, and a request
  is made only when its 5 bytes fit (so reports pause, bounded, rather than overflow).
  A ``Resend`` means Marlin flushed that buffer, S000 lines with it.  Nothing in ``M115`` announces the
  feature, so ``probe_realtime_reports`` asks once at connect.  Marlin's ``M154``
  auto-report (``Cap:AUTOREPORT_POS``) and plain ``M114`` print the *planned* position
  (``report_current_position_projected``): evidence of planning, like ``ok``, not of
  motion, so they are not used.

Every request is a ``Write`` action the link applies under its lock, never emitted once the
session failed or was emergency-stopped (``_write``): a report never follows the stop on the wire, and the
stop never waits for more than one such write.  Requests and reports are counted: the
n-th report answers the n-th request or a later one (a request lost on the wire is never
answered), so ``asked_at`` of a report is a time at or before the moment it was made."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from .dialects import Dialect
from .events import PositionReport, ReplyEvent, StatusReport

MARLIN_MAX_PENDING = 16  # S000 lines that may wait in Marlin's receive buffer at once


@dataclass(frozen=True)
class PositionMark:
    """A reported real position (mm, the program's work frame), the link's completion
    count when it arrived (``Link.status_marks`` semantics) and host times: a time at or
    before the report was made (``asked_at``), and its arrival (``received_at``)."""

    position: tuple[float, float, float]
    completed: int
    asked_at: float
    received_at: float
    moving: bool | None = None  # the controller's state said so (grbl Run/Jog/Home, Marlin S_XYZ:5)


class PositionTracker:
    """Requests and reports of the real position (see module).  ``marks``: the last 64
    reports; ``interval_s`` > 0: ``poll`` asks this often (``Machine.stream`` sets it);
    ``realtime``: Marlin answered ``S000`` (``Link.probe_realtime_reports``); ``reported``:
    reports received; ``rt_pending``: Marlin ``S000`` lines not yet acknowledged."""

    def __init__(self, rules: Dialect) -> None:
        self.rules = rules
        self.marks: deque[PositionMark] = deque(maxlen=64)
        self.interval_s = 0.0
        self.realtime = False
        self.reported = 0
        self.rt_pending = 0
        self._asks: deque[float] = deque(maxlen=4096)
        self._asked = 0  # requests written since the link opened
        self._last_ask = 0.0
        self._wco: tuple[float, ...] | None = None
        self._candidate: tuple[PositionReport, list[ReplyEvent] | None] | None = None

    # ------------------------------------------------------------------ requests
    def ask(self, now: float, *, queued: bool = False) -> bytes:
        """Note a request made at ``now`` and return its bytes (``queued``: Marlin
        ``S000``, which its queue acknowledges later with a plain ``ok``)."""
        self._asked += 1
        self._asks.append(now)
        self._last_ask = now
        if queued:
            self.rt_pending += 1
        return self.rules.position_request

    def poll(self, now: float, in_flight_bytes: int, rx_buffer: int) -> bytes | None:
        """The request to write now (``interval_s`` has passed and, for a queued request,
        its bytes fit the controller's receive buffer beside ``in_flight_bytes``), or None."""
        if self.interval_s <= 0 or now - self._last_ask < self.interval_s:
            return None
        request = self.rules.position_request
        if not self.rules.request_queued:  # a real-time byte (grbl ?): always answered
            return self.ask(now)
        if self.realtime and self.rt_pending < MARLIN_MAX_PENDING \
                and in_flight_bytes + self.reserved_bytes() + len(request) <= rx_buffer - 1:
            return self.ask(now, queued=True)
        return None

    def reserved_bytes(self) -> int:
        """Marlin receive-buffer bytes taken by S000 lines not yet acknowledged."""
        return len(self.rules.position_request) * self.rt_pending if self.rules.request_queued else 0

    def flushed(self) -> None:
        """Marlin answered ``Resend``: it flushed its receive buffer, S000 lines with it."""
        self.rt_pending = 0

    def _asked_at(self, now: float) -> float:
        """A time at or before the report being received now was made (see module)."""
        lost = self._asked - len(self._asks)  # requests older than the kept times
        index = self.reported - 1 - lost
        if 0 <= index < len(self._asks):
            return self._asks[index]
        return self._asks[0] if self._asks else now

    # ------------------------------------------------------------------ replies
    def on_status(self, event: StatusReport, now: float, completed: int) -> PositionMark | None:
        """grbl: a status report is a position report (WPos, or MPos - WCO)."""
        self.reported += 1
        wco = event.fields.get("WCO")
        if wco:
            try:
                self._wco = tuple(float(v) for v in wco.split(","))
            except ValueError:
                pass
        if event.wpos is not None:
            position: tuple[float, ...] = tuple(event.wpos)
        elif event.mpos is not None:
            offset = self._wco or (0.0, 0.0, 0.0)
            position = tuple(m - o for m, o in zip(event.mpos, offset))
        else:
            return None
        state = event.state.split(":")[0]
        return self._mark(position, now, completed, state != "Idle")

    def on_position_line(self, event: ReplyEvent, now: float, head: list[ReplyEvent] | None,
                         completed: int) -> tuple[bool, PositionMark | None]:
        """Marlin: remember a position line (it may be an S000 answer, confirmed by the
        ``S_XYZ:`` line after it; ``head``: the replies of the command in flight, where
        the line went meanwhile).  Returns (consumed, mark): consumed when ``event`` was
        that confirmation."""
        if isinstance(event, PositionReport):
            self._candidate = (event, head)
            return False, None
        if not event.raw.startswith("S_XYZ:"):
            return False, None
        candidate, self._candidate = self._candidate, None
        self.reported += 1
        state = event.raw[len("S_XYZ:"):].strip()
        if candidate is None:
            return True, None
        report, replies = candidate
        if replies is not None and report in replies:
            replies.remove(report)  # not the answer of the command in flight
        axes = report.axes
        if not all(a in axes for a in "XYZ"):
            return True, None
        return True, self._mark((axes["X"], axes["Y"], axes["Z"]), now, completed, state != "3")  # M_IDLE 3

    def on_plain_ok(self, extra: str) -> None:
        """Marlin: a plain ``ok`` (no line number) may acknowledge an S000 line."""
        if self.rt_pending > 0 and not extra.startswith("T:"):
            self.rt_pending -= 1

    def _mark(self, position: tuple[float, ...], now: float, completed: int,
              moving: bool | None) -> PositionMark | None:
        if len(position) < 3:
            return None
        x, y, z = (float(v) for v in position[:3])
        mark = PositionMark((x, y, z), completed, self._asked_at(now), now, moving)
        self.marks.append(mark)
        return mark
