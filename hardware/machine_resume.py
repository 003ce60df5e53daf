"""Resume support of ``hardware.machine.Machine`` (a mixin): the modal replay before a
resumed stream, the bound on what really moved when a controller reset (``ok`` means
planned), and draining the lines a controller still runs after it rejected one."""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import replace
from typing import TYPE_CHECKING

from .errors import FirmwareError, FirmwareReset, HardwareError, MachineStateError
from .events import PositionReport
from .machine_types import ReportEvidence, _Interrupted
from .resume import (
    POSITION_TOLERANCE_MM,
    ReportedResume,
    ResumeLocation,
    command_feeds,
    count_moves,
    end_positions,
    executed_bound,
    locate_by_position,
    locate_by_report,
    modal_preamble,
    planner_blocks,
)

if TYPE_CHECKING:
    from .link import PendingCommand
    from .machine_host import SerialHost


class ResumeOperations:
    """Part of ``Machine`` (what it uses of it: ``hardware.machine_host.SerialHost``)."""

    # what these methods set (declared with their types in SerialHost)
    _interrupted: _Interrupted | None
    last_preamble: list[str]
    rejected_lines: list[int]
    last_resume: ResumeLocation | None
    _resume_commands: list[str] | None
    _stream_started: float | None
    _stream_origin: tuple[float, float, float] | None

    def resume_line(self: SerialHost) -> int:
        """After reconnecting: index of the first command not known to be executed."""
        gap = self._interrupted
        if gap is None:
            raise MachineStateError("no interrupted program to resume", field="state")
        if self.link is None:
            raise MachineStateError("connect before resuming", field="state", value="disconnected")
        if self.rules.resets_on_connect or gap.reset:
            return gap.moved_index if gap.moved_index is not None else gap.acked_index
        if not gap.inflight:
            return gap.acked_index
        first_line = gap.inflight[0][0]
        assert first_line is not None, "a controller numbering lines numbered every line sent"
        last = self.link.sync_line_number(first_line)
        if gap.acked_line_no is not None and last < gap.acked_line_no:
            self.link.reset_line_numbers(1)  # the firmware restarted meanwhile
            return gap.acked_index
        done = [index + 1 for number, index in gap.inflight if number is not None and number <= last]
        return max([gap.acked_index, *done])

    def adopt_interrupted(self: SerialHost, total: int, acked_index: int, acked_line_no: int | None) -> None:
        """Before ``connect`` in a new host process: take over what an earlier process
        recorded of an interrupted program (commands [0, acked_index) acknowledged, the
        last of them numbered ``acked_line_no``; later commands were numbered on from
        it), so that ``connect`` keeps the firmware's line numbering and ``resume_line``
        can ask the firmware which of the later lines it accepted."""
        if self.link is not None:
            raise MachineStateError("adopt an interrupted program before connecting", field="state",
                                    value=self.state)
        inflight: list[tuple[int | None, int]] = [] if acked_line_no is None else \
            [(acked_line_no + 1 + k, acked_index + k) for k in range(total - acked_index)]
        self._interrupted = _Interrupted(total, acked_index, acked_line_no, inflight,
                                         reset=acked_line_no is None)

    def _replay_modes(self: SerialHost, commands: list[str], start_line: int) -> None:
        """Before a program's first command: every process output off (``safe_off``), so a
        program starts with them off unless it turns them on.  Resuming mid-program, then
        restore units, coordinate system, motion mode, feed, the start point, distance mode
        and the dispenser as the skipped commands left them (the dispenser goes back on only
        where the program had it on).  ``last_preamble``: what the stream sent before command
        ``start_line`` (``safe_off``; resuming, then the modal replay without its own
        ``dispense_off``, already sent)."""
        self.last_preamble = []
        p = self.profile
        if self._send_safe_off("program"):
            self.last_preamble = list(p.safe_off)
        if start_line == 0:
            return
        preamble = modal_preamble(commands, start_line, dispense_on=p.dispense_on,
                                  dispense_off=p.dispense_off, clearance_z=p.clearance_z)
        if preamble[:1] == [p.dispense_off]:
            preamble = preamble[1:]  # sent with safe_off
        for command in preamble:
            self.live_link.send(command, self.timeout_s * 10)
        self.last_preamble = [*p.safe_off, *preamble]

    @property
    def held_moves(self: SerialHost) -> int:
        """Acknowledged moves the controller may hold unmoved: its planner's blocks plus what
        its stepper holds after the planner released them (``Dialect.stepper_queue``: grbl's
        step segments, each possibly the end of another short block)."""
        return self.planner_blocks + self.rules.stepper_queue

    def _moved_bound(self: SerialHost, commands: list[str], acked: int, seqs: dict[int, int]) -> int:
        """First command not known to have *moved* (``ok`` = planned): from what the
        controller can hold (``held_moves``), tightened by the last grbl status report (Idle:
        nothing held; ``Bf:`` free planner blocks, plus the stepper's) that came after some
        of the acknowledgements."""
        p = self.profile
        self._resume_commands = list(commands)  # for locate_resume after the reconnect
        blocks = planner_blocks(commands, p.dispense_on, p.dispense_off)
        bound = executed_bound(blocks, acked, self.held_moves)
        marks = list(self.link.status_marks) if self.link is not None else []
        for status, completed, _ in reversed(marks):
            done = [i for i, seq in seqs.items() if seq is not None and seq <= completed]
            if not done:
                continue
            free = status.fields.get("Bf", "")
            if status.state.split(":")[0] in ("Idle", "Alarm", "Check"):
                pending = 0
            elif "," in free:
                pending = max(self.planner_blocks - int(free.split(",")[0]), 0) + self.rules.stepper_queue
            else:
                pending = self.held_moves
            return max(bound, executed_bound(blocks, max(done) + 1, pending))
        return bound

    def _note_stream_start(self: SerialHost, start_line: int) -> None:
        """Before a stream: only reports asked for from now on are evidence about it, and
        (a stream from its first command) where the tool stands still, so that the
        program's opening move, from wherever the tool was, is placeable too."""
        self._stream_started = started = time.monotonic()
        self._stream_origin = None
        link = self.link
        if start_line != 0 or link is None:
            return
        try:
            if not self.rules.request_queued:  # a real-time status (grbl): always available
                link.query_status()
            elif not (link.realtime_reports and link.probe_realtime_reports(min(1.0, self.timeout_s))):
                return
        except HardwareError:
            return
        mark = link.position_marks[-1] if link.position_marks else None
        if mark is not None and mark.moving is False and mark.asked_at >= started:
            self._stream_origin = mark.position

    def _report_evidence(self: SerialHost, seqs: dict[int, int], start_line: int,
                         exc: Exception) -> ReportEvidence | None:
        """The last real position reported during the stream, before the link failed
        (``hardware.reports``), with the commands acknowledged when it arrived; None when
        there was none."""
        started = self._stream_started
        marks = [m for m in (self.link.position_marks if self.link is not None else [])
                 if started is not None and m.asked_at >= started]
        if not marks:
            return None
        mark = marks[-1]
        done = [i for i, seq in seqs.items() if seq is not None and seq <= mark.completed]
        acked = max(done) + 1 if done else start_line
        stopped = self.live_link.failed_at if isinstance(exc, FirmwareReset) else None
        return ReportEvidence(mark.position, max(acked, start_line), mark.asked_at, stopped,
                              self._stream_origin)

    def locate_resume(self: SerialHost) -> ResumeLocation:
        """After reconnecting: where the interrupted program continues, and on what evidence.

        Marlin that kept running answers by line numbers (exact).  After a controller reset
        (grbl always: its board resets on reconnect), ``resume_line()`` is the planner bound:
        up to a planner's worth of acknowledged short moves may have been lost.  Then the
        controller is asked where the tool stands (grbl status, Marlin ``M114``); when that
        position is believable (not the power-on origin) and lies on exactly
        one place of the program between the bound and the last command sent (a controller that
        lost its position reports something else: it is believed only on the path), the program
        continues there: at the move the tool stopped in, or after the move it finished
        (:func:`hardware.resume.locate_by_position`).  A controller that lost its position
        (a reset) is placed by the last real position it *reported while streaming*
        (``hardware.reports``; basis ``reported position``, with the bound on what may run
        twice).  Otherwise the bound stands, and ``detail`` says why.  Must run before
        re-homing.  Sets ``last_resume``."""
        bound = self.resume_line()
        gap = self._interrupted
        assert gap is not None  # resume_line() raised otherwise
        if not self.rules.resets_on_connect and not gap.reset:
            found = ResumeLocation(bound, "line numbers", "the controller kept running and numbering lines")
        else:
            sent = gap.acked_index + len(gap.inflight)
            found = self._locate_by_position(bound, gap.acked_index, sent, gap.total)
            if found.basis == "planner bound" and gap.report is not None:
                found = self._locate_by_report(found, gap.report, sent, gap.total)
        found = self._with_repeats(found, gap.acked_index + len(gap.inflight))
        self.last_resume = found
        return found

    def _with_repeats(self: SerialHost, found: ResumeLocation, sent: int) -> ResumeLocation:
        """``found`` with what may run twice counted: by line numbers nothing; by position the
        move the tool stood in; by a reported position its bound; by the planner bound every
        command from the start up to the last one sent (any of them may have moved)."""
        if found.basis == "line numbers":
            last = found.start
        elif found.basis == "position":
            last = found.start + 1
        elif found.basis == "reported position" and found.repeat_bound_lines is not None:
            last = found.start + found.repeat_bound_lines
        else:
            last = max(sent, found.start)
        commands = self._resume_commands or []
        last = min(last, len(commands)) if commands else last
        moves = count_moves(commands[found.start:last]) if commands else last - found.start
        return replace(found, repeats=max(last - found.start, 0), repeat_moves=moves)

    def _locate_by_report(self: SerialHost, fallback: ResumeLocation, report: ReportEvidence, sent: int,
                          total: int) -> ResumeLocation:
        """The controller lost its position: place the last position it reported while
        streaming on the program (``hardware.resume.locate_by_report``).  A real position is
        evidence: it is used whether it lies after the bound (fewer repeats) or before it
        (the bound assumed less was held than really was: resume earlier, never skip)."""
        commands = self._resume_commands
        if commands is None or len(commands) != total:
            return fallback
        p = self.profile
        blocks = planner_blocks(commands, p.dispense_on, p.dispense_off)
        lo = executed_bound(blocks, report.acked_index, self.held_moves)
        stopped = report.stopped_at if report.stopped_at is not None else (
            self._connected_at if self._connected_at is not None else time.monotonic())
        seconds = max(stopped - report.asked_at, 0.0)
        ends = end_positions(commands, p.dispense_on, p.dispense_off, start=report.origin)
        opening = next((k for k, end in enumerate(ends) if end is not None), len(ends))
        where = "(" + ", ".join(f"{v:.3f}" for v in report.position) + ")"
        if report.origin is None and lo <= opening:
            # the tool may still have been on the opening move, from a place the program does not
            # give: a point there could also lie on a later part of the path
            return ResumeLocation(fallback.start, fallback.basis, f"{fallback.detail}; the last reported position "
                                  f"{where} may lie on the program's opening move, whose start is not known")
        found = locate_by_report(ends, command_feeds(commands, p.dispense_on, p.dispense_off), report.position,
                                 lo, max(sent, fallback.start), seconds, acked=report.acked_index,
                                 origin=report.origin)
        if found is None:
            return ResumeLocation(fallback.start, fallback.basis, f"{fallback.detail}; the last reported position "
                                  f"{where} is not at one place of commands {lo}..{max(sent, fallback.start)}")
        found = _not_past_a_move_end(found, ends, report.position, lo)
        behind = "" if found.start >= fallback.start else \
            "; it lies before the planner bound, so the resume starts there (earlier)"
        mm = "the path up to the last command sent" if found.after_mm is None else f"{found.after_mm:.3f} mm"
        total_mm = "" if found.bound_mm is None else f"{found.bound_mm:.3f} mm, "
        detail = (f"the controller reset; {seconds * 1000:.0f} ms before it stopped the tool was reported at "
                  f"{where}, in command {found.start}: at most {total_mm}{found.bound_lines} commands may run "
                  f"twice ({found.before_mm:.3f} mm of command {found.start} before that point, then at most "
                  f"{mm} of motion up to the reset); the planner bound was command {fallback.start}{behind}")
        return ResumeLocation(found.start, "reported position", detail, found.bound_mm, found.bound_lines)

    def _locate_by_position(self: SerialHost, bound: int, acked: int, sent: int, total: int) -> ResumeLocation:
        commands = self._resume_commands
        fallback = "planner bound"
        if commands is None or len(commands) != total:
            return ResumeLocation(bound, fallback, "the program is not known to this process")
        self._claim("busy")
        try:
            if self.rules.position_by_status:
                # an Alarm at boot (homing required) is no evidence either way: a board whose
                # reset zeroed its position reports the origin, refused below
                status = self.live_link.query_status()
                position = status.wpos or status.mpos
            else:
                report = self.live_link.send("M114", self.timeout_s).payload
                position = (tuple(report.axes.get(a, 0.0) for a in "XYZ")
                            if isinstance(report, PositionReport) else None)
        finally:
            self._release("idle")
        if position is None:
            return ResumeLocation(bound, fallback, "the controller reported no position")
        x, y, z = (float(v) for v in position[:3])
        position = (x, y, z)
        if all(abs(v) < 1e-9 for v in position):
            return ResumeLocation(bound, fallback, "the controller reports the power-on origin: its position "
                                                   "was lost with the reset")
        p = self.profile
        start = locate_by_position(end_positions(commands, p.dispense_on, p.dispense_off), position, bound,
                                   max(sent, bound), acked=acked)
        where = "(" + ", ".join(f"{v:.3f}" for v in position) + ")"
        if start is None:
            return ResumeLocation(bound, fallback, f"the tool at {where} is not at one place of commands "
                                                   f"{bound}..{max(sent, bound)}")
        return ResumeLocation(start, "position", f"the tool stood at {where}: command {start} is the first "
                                                 "not completed")

    def _drain_after_rejection(self: SerialHost, exc: FirmwareError, inflight: deque[tuple[int, PendingCommand]],
                               executed: int) -> int:
        """A line was rejected: the controller still runs the lines it already holds
        (grbl: up to a buffer's worth).  Wait for each answer; return the index after the
        last one answered, and name the rejected line in ``exc.line_index``."""
        failed, _ = inflight.popleft()
        exc.line_index = failed
        executed = failed + 1
        rejected = [failed]
        while inflight:
            index, pending = inflight.popleft()
            try:
                outcome = pending.result(self.timeout_s * 10, check=False)
            except HardwareError:
                break
            if outcome.status == "error":
                rejected.append(index)
            executed = index + 1
        self.rejected_lines = rejected
        return executed


def _not_past_a_move_end(found: ReportedResume, ends: list[tuple[float, float, float] | None],
                         position: tuple[float, float, float], lo: int) -> ReportedResume:
    """A tool *moving* when reported and within the tolerance of a move's end may still be
    finishing that move (the report rounds, the tolerance is wider than a step): resume at
    that move, not after it (it runs again whole; never a step of it skipped)."""
    start = found.start
    while start > lo and (end := ends[start - 1]) is not None and math.dist(end, position) <= POSITION_TOLERANCE_MM:
        start -= 1
    if start == found.start:
        return found
    again = sum(math.dist(a, b) for k in range(start, found.start) if k > 0
                and (a := ends[k - 1]) is not None and (b := ends[k]) is not None)
    return replace(found, start=start, bound_lines=found.bound_lines + found.start - start,
                   bound_mm=None if found.bound_mm is None else found.bound_mm + again,
                   before_mm=found.before_mm + again)
