"""Position reports during streaming (a mixin of ``hardware.link.Link``): where motion
really is, asked for at a bounded rate by the reader thread, so that after a controller
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

Every request is a real-time write under the link's lock, refused once the link failed or
was emergency-stopped (``_write``): a report never follows the stop on the wire, and the
stop never waits for more than one such write.  Requests and reports are counted: the
n-th report answers the n-th request or a later one (a request lost on the wire is never
answered), so ``asked_at`` of a report is a time at or before the moment it was made."""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

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


class PositionReports:
    """Mixin of ``Link``; every method runs with the link's condition held unless said."""

    def _reports_init(self) -> None:
        self.position_marks: deque[PositionMark] = deque(maxlen=64)
        self.report_interval_s = 0.0  # > 0: the reader asks this often (Machine.stream sets it)
        self.realtime_reports = False  # Marlin: S000 answered (probe_realtime_reports)
        self.failed_at: float | None = None  # host time the link became fatal
        self._asks: deque[float] = deque(maxlen=4096)
        self._asked = 0  # requests written since the link opened
        self._reported = 0  # reports received
        self._last_ask = 0.0
        self._rt_pending = 0  # Marlin S000 lines not yet acknowledged by the queue
        self._wco: tuple[float, ...] | None = None
        self._candidate: tuple[PositionReport, list | None] | None = None

    def _note_ask(self) -> None:
        now = time.monotonic()
        self._asked += 1
        self._asks.append(now)
        self._last_ask = now

    def _report_asked_at(self) -> float:
        """A time at or before the report being received now was made (see module)."""
        lost = self._asked - len(self._asks)  # requests older than the kept times
        index = self._reported - 1 - lost
        if 0 <= index < len(self._asks):
            return self._asks[index]
        return self._asks[0] if self._asks else time.monotonic()

    def _poll_reports(self) -> None:
        """Reader thread: ask for a position when the interval has passed."""
        if self.report_interval_s <= 0 or self._fatal is not None or self._closed:
            return
        if time.monotonic() - self._last_ask < self.report_interval_s:
            return
        request = self.rules.position_request
        if not self.rules.request_queued:  # a real-time byte (grbl ?): always answered
            self._note_ask()
            self._write(request)
        elif self.realtime_reports and self._rt_pending < MARLIN_MAX_PENDING \
                and sum(len(p.data) for p in self._outstanding) + self._reserved_bytes() \
                + len(request) <= self.rx_buffer - 1:
            self._note_ask()
            self._rt_pending += 1
            self._write(request)

    def _reserved_bytes(self) -> int:
        """Marlin receive-buffer bytes taken by S000 lines not yet acknowledged."""
        return len(self.rules.position_request) * self._rt_pending

    # ------------------------------------------------------------------ replies
    def _on_status_position(self, event: StatusReport) -> None:
        """grbl: a status report is a position report (WPos, or MPos - WCO)."""
        self._reported += 1
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
        self._mark(position, state != "Idle")

    def _on_position_line(self, event: ReplyEvent) -> bool:
        """Marlin: remember a position line (it may be an S000 answer, confirmed by the
        ``S_XYZ:`` line after it); True when ``event`` was that confirmation (consumed)."""
        if isinstance(event, PositionReport):
            head = self._outstanding[0].replies if self._outstanding else None
            self._candidate = (event, head)
            return False
        if not event.raw.startswith("S_XYZ:"):
            return False
        candidate, self._candidate = self._candidate, None
        self._reported += 1
        state = event.raw[len("S_XYZ:"):].strip()
        if candidate is not None:
            report, replies = candidate
            if replies is not None and report in replies:
                replies.remove(report)  # not the answer of the command in flight
            axes = report.axes
            if all(a in axes for a in "XYZ"):  # M_IDLE 3; anything else may move
                self._mark((axes["X"], axes["Y"], axes["Z"]), state != "3")
        return True

    def _on_plain_ok(self, extra: str) -> None:
        """Marlin: a plain ``ok`` (no line number) may acknowledge an S000 line."""
        if self._rt_pending > 0 and not extra.startswith("T:"):
            self._rt_pending -= 1

    def _mark(self, position: tuple[float, ...], moving: bool | None = None) -> None:
        xyz = tuple(float(v) for v in position[:3])
        if len(xyz) == 3:
            self.position_marks.append(PositionMark(xyz, self._completed, self._report_asked_at(),  # type: ignore[arg-type]
                                                    time.monotonic(), moving))

    # ------------------------------------------------------------------ connect-time probe
    def probe_realtime_reports(self, timeout_s: float = 1.0) -> bool:
        """Marlin, idle, after ``M115``: send one ``S000`` and wait for its answer and its
        ``ok``; True when the firmware answered with a position (REALTIME_REPORTING_COMMANDS).
        A firmware without it answers ``Unknown command`` and ``ok``.  Not locked by the
        caller."""
        if not self.rules.request_queued:
            return False
        with self._cond:
            self._check_fatal()
            before = self._reported
            self._note_ask()
            self._rt_pending += 1
            self._write(self.rules.position_request)
            deadline = time.monotonic() + timeout_s
            while (self._rt_pending > 0 or self._reported == before) and time.monotonic() < deadline:
                self._check_fatal()
                if self._rt_pending == 0 and self._reported == before:
                    break  # acknowledged without an answer: not supported
                self._cond.wait(0.02)
            self.realtime_reports = self._reported > before
            return self.realtime_reports
