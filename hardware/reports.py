"""Position reports during streaming (a mixin of ``hardware.session.ReplySession``, pure:
every method takes ``now``): where motion really is, asked for at a bounded rate while the
reader thread ticks the session, so that after a controller
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

from .events import PositionReport, ReplyEvent, StatusReport
from .session_types import Position

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


class PositionReports:
    """Mixin of ``ReplySession``; pure (times are the ``now`` arguments)."""

    def _reports_init(self) -> None:
        self.position_marks: deque[PositionMark] = deque(maxlen=64)
        self.report_interval_s = 0.0  # > 0: the reader asks this often (Machine.stream sets it)
        self.realtime_reports = False  # Marlin: S000 answered (Link.probe_realtime_reports)
        self._asks: deque[float] = deque(maxlen=4096)
        self._asked = 0  # requests written since the link opened
        self.reported = 0  # reports received
        self._last_ask = 0.0
        self.rt_pending = 0  # Marlin S000 lines not yet acknowledged by the queue
        self._wco: tuple[float, ...] | None = None
        self._candidate: tuple[PositionReport, list | None] | None = None

    def _note_ask(self, now: float) -> None:
        self._asked += 1
        self._asks.append(now)
        self._last_ask = now

    def _report_asked_at(self, now: float) -> float:
        """A time at or before the report being received now was made (see module)."""
        lost = self._asked - len(self._asks)  # requests older than the kept times
        index = self.reported - 1 - lost
        if 0 <= index < len(self._asks):
            return self._asks[index]
        return self._asks[0] if self._asks else now

    def ask_status(self, now: float) -> list:
        """Ask for one real-time report (grbl ``?``; dialects whose request is not queued)."""
        self._note_ask(now)
        self._write(self.rules.position_request, "report")
        return self._take()

    def ask_queued_report(self, now: float) -> list:
        """Marlin: one ``S000`` (it is also acknowledged by a plain ``ok``)."""
        self._note_ask(now)
        self.rt_pending += 1
        self._write(self.rules.position_request, "report")
        return self._take()

    def poll_reports(self, now: float) -> list:
        """Reader tick: ask for a position when ``report_interval_s`` has passed."""
        if self.report_interval_s <= 0 or self.fatal is not None:
            return self._take()
        if now - self._last_ask < self.report_interval_s:
            return self._take()
        request = self.rules.position_request
        if not self.rules.request_queued:  # a real-time byte (grbl ?): always answered
            self._note_ask(now)
            self._write(request, "report")
        elif self.realtime_reports and self.rt_pending < MARLIN_MAX_PENDING \
                and sum(len(p.data) for p in self.outstanding) + self._reserved_bytes() \
                + len(request) <= self.rx_buffer - 1:
            self._note_ask(now)
            self.rt_pending += 1
            self._write(request, "report")
        return self._take()

    def _reserved_bytes(self) -> int:
        """Marlin receive-buffer bytes taken by S000 lines not yet acknowledged."""
        return len(self.rules.position_request) * self.rt_pending

    # ------------------------------------------------------------------ replies
    def _on_status_position(self, event: StatusReport, now: float) -> None:
        """grbl: a status report is a position report (WPos, or MPos - WCO)."""
        self.reported += 1
        wco = event.fields.get("WCO")
        if wco:
            try:
                self._wco = tuple(float(v) for v in wco.split(","))
            except ValueError:
                pass
        if event.wpos is not None:
            position = event.wpos
        elif event.mpos is not None:
            offset = self._wco or (0.0, 0.0, 0.0)
            position = tuple(m - o for m, o in zip(event.mpos, offset))
        else:
            return
        state = event.state.split(":")[0]
        self._mark(position, now, state != "Idle")

    def _on_position_line(self, event: ReplyEvent, now: float) -> bool:
        """Marlin: remember a position line (it may be an S000 answer, confirmed by the
        ``S_XYZ:`` line after it); True when ``event`` was that confirmation (consumed)."""
        if isinstance(event, PositionReport):
            head = self.outstanding[0].replies if self.outstanding else None
            self._candidate = (event, head)
            return False
        if not event.raw.startswith("S_XYZ:"):
            return False
        candidate, self._candidate = self._candidate, None
        self.reported += 1
        state = event.raw[len("S_XYZ:"):].strip()
        if candidate is not None:
            report, replies = candidate
            if replies is not None and report in replies:
                replies.remove(report)  # not the answer of the command in flight
            axes = report.axes
            if all(a in axes for a in "XYZ"):  # M_IDLE 3; anything else may move
                self._mark((axes["X"], axes["Y"], axes["Z"]), now, state != "3")
        return True

    def _on_plain_ok(self, extra: str) -> None:
        """Marlin: a plain ``ok`` (no line number) may acknowledge an S000 line."""
        if self.rt_pending > 0 and not extra.startswith("T:"):
            self.rt_pending -= 1

    def _mark(self, position: tuple[float, ...], now: float, moving: bool | None = None) -> None:
        xyz = tuple(float(v) for v in position[:3])
        if len(xyz) == 3:
            mark = PositionMark(xyz, self.completed, self._report_asked_at(now), now, moving)  # type: ignore[arg-type]
            self.position_marks.append(mark)
            self._actions.append(Position(mark))
