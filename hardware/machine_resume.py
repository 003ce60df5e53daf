"""Resume support of the serial machine: :class:`ResumeHelper`, built with the machine's
``SerialCommands``, its ``GrblControl`` (how many moves the controller may hold) and its
``OutputGuard`` (``safe_off`` before a program).  It reads and refines what is known of an
interrupted program (the ``InterruptedProgram`` kept in the machine state), settles it on
reconnect, replays the modal state before a resumed stream, bounds what really moved when a
controller reset (``ok`` means planned), locates the resume point from the controller's
position or its reports, and drains the lines a controller still runs after it rejected
one."""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import replace
from typing import Any

from .errors import FirmwareError, FirmwareReset, HardwareError, MachineStateError
from .events import PositionReport
from .link import PendingCommand
from .machine_grbl import GrblControl
from .machine_host import SerialCommands
from .machine_outputs import OutputGuard
from .machine_state import InterruptedProgram
from .machine_types import ReportEvidence
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

__all__ = ["ResumeHelper"]


class ResumeHelper:
    """An interrupted program and its resume (see the module docstring)."""

    def __init__(self, commands: SerialCommands, grbl: GrblControl, outputs: OutputGuard) -> None:
        self.commands = commands
        self.grbl = grbl
        self.outputs = outputs
        self.program: list[str] | None = None  # the interrupted program's commands (locate_resume)
        self.last_preamble: list[str] = []  # what the last stream sent before its first command
        self.rejected_lines: list[int] = []  # command indices the controller rejected
        self.last_resume: ResumeLocation | None = None  # what locate_resume found last
        self.connected_at: float | None = None  # time.monotonic() of the last connect
        self.stream_started: float | None = None  # time.monotonic() when the last stream started
        self.stream_origin: tuple[float, float, float] | None = None  # where the tool stood before it, mm

    @property
    def interrupted(self) -> InterruptedProgram | None:
        """What is known of the program a failure stopped (``MachineState.interrupted``)."""
        return self.commands.state.interrupted

    @interrupted.setter
    def interrupted(self, gap: InterruptedProgram | None) -> None:
        self.commands.state.interrupted = gap

    def resume_line(self) -> int:
        """After reconnecting: index of the first command not known to be executed: what
        the record tells alone (``InterruptedProgram.known_resume``), else the commands in
        flight that the firmware's line number says it took."""
        gap = self.interrupted
        if gap is None:
            raise MachineStateError("no interrupted program to resume", field="state")
        link = self.commands.state.link
        if link is None:
            raise MachineStateError("connect before resuming", field="state", value="disconnected")
        known = gap.known_resume(self.commands.rules.resets_on_connect)
        if known is not None:
            return known
        first_line = gap.inflight[0][0]
        assert first_line is not None, "a controller numbering lines numbered every line sent"
        last = link.sync_line_number(first_line)
        if gap.acked_line_no is not None and last < gap.acked_line_no:
            link.reset_line_numbers(1)  # the firmware restarted meanwhile
            return gap.acked_index
        done = [index + 1 for number, index in gap.inflight if number is not None and number <= last]
        return max([gap.acked_index, *done])

    def adopt_interrupted(self, total: int, acked_index: int, acked_line_no: int | None) -> None:
        """Before ``connect`` in a new host process: take over what an earlier process
        recorded of an interrupted program (commands [0, acked_index) acknowledged, the
        last of them numbered ``acked_line_no``; later commands were numbered on from
        it), so that ``connect`` keeps the firmware's line numbering and ``resume_line``
        can ask the firmware which of the later lines it accepted."""
        if self.commands.state.link is not None:
            raise MachineStateError("adopt an interrupted program before connecting", field="state",
                                    value=self.commands.state.state)
        self.interrupted = InterruptedProgram.adopted(total, acked_index, acked_line_no)

    def settle_on_connect(self, reset: bool) -> None:
        """Once connected (``reset``: the controller announced a restart): a controller that
        kept running through a lost link (a Marlin board that does not reset on connect)
        still holds the interrupted program's queue.  Settle where the program stands by line
        numbers (``resume_line``) before anything else is sent, so that the ``safe_off``
        queued after it leaves the resume unchanged."""
        gap = self.interrupted
        rules = self.commands.rules
        if gap is None or reset or gap.reset or rules.resets_on_connect or not rules.line_numbers:
            return
        try:
            settled = self.resume_line()
        except FirmwareReset:  # it restarted after all: its outputs are off, numbering starts again
            gap.reset = True
            self.commands.link.reset_line_numbers(1)
        else:
            gap.acked_index, gap.inflight = settled, []

    def program_status(self) -> dict[str, Any] | None:
        """The program on this machine: while it runs ``{"state": "printing"|"paused",
        "line", "total"}`` (commands acknowledged so far, of the total); after it stopped on
        a lost link or a rejected line ``{"state": "interrupted", "line", "total",
        "resume_line"}``: commands known processed, and the first command a resume would
        send when that is known without asking the controller (a controller that reset: its
        planner bound or a located resume; a Marlin that kept running: once the reconnect
        settled it by line numbers), else None.  The interrupted program waits for an
        operator to resume (``stream(start_line=...)``) or abandon it; None when neither."""
        located = self.last_resume
        return self.commands.state.program_status(self.commands.rules.resets_on_connect,
                                                  located.start if located is not None else None)

    def replay_modes(self, commands: list[str], start_line: int) -> None:
        """Before a program's first command: every process output off (``safe_off``), so a
        program starts with them off unless it turns them on.  Resuming mid-program, then
        restore units, coordinate system, motion mode, feed, the start point, distance mode
        and the dispenser as the skipped commands left them (the dispenser goes back on only
        where the program had it on).  ``last_preamble``: what the stream sent before command
        ``start_line`` (``safe_off``; resuming, then the modal replay without its own
        ``dispense_off``, already sent)."""
        self.last_preamble = []
        p = self.commands.profile
        if self.outputs.send_safe_off("program"):
            self.last_preamble = list(p.safe_off)
        if start_line == 0:
            return
        preamble = modal_preamble(commands, start_line, dispense_on=p.dispense_on,
                                  dispense_off=p.dispense_off, clearance_z=p.clearance_z)
        if preamble[:1] == [p.dispense_off]:
            preamble = preamble[1:]  # sent with safe_off
        for command in preamble:
            self.commands.send(command)
        self.last_preamble = [*p.safe_off, *preamble]

    def moved_bound(self, commands: list[str], acked: int, seqs: dict[int, int]) -> int:
        """First command not known to have *moved* (``ok`` = planned): from what the
        controller can hold (``held_moves``), tightened by the last grbl status report (Idle:
        nothing held; ``Bf:`` free planner blocks, plus the stepper's) that came after some
        of the acknowledgements."""
        p = self.commands.profile
        self.program = list(commands)  # for locate_resume after the reconnect
        blocks = planner_blocks(commands, p.dispense_on, p.dispense_off)
        bound = executed_bound(blocks, acked, self.grbl.held_moves)
        link = self.commands.state.link
        marks = list(link.status_marks) if link is not None else []
        for status, completed, _ in reversed(marks):
            done = [i for i, seq in seqs.items() if seq is not None and seq <= completed]
            if not done:
                continue
            free = status.fields.get("Bf", "")
            if status.state.split(":")[0] in ("Idle", "Alarm", "Check"):
                pending = 0
            elif "," in free:
                pending = max(self.grbl.planner_blocks - int(free.split(",")[0]), 0) + self.commands.rules.stepper_queue
            else:
                pending = self.grbl.held_moves
            return max(bound, executed_bound(blocks, max(done) + 1, pending))
        return bound

    def note_stream_start(self, start_line: int) -> None:
        """Before a stream: only reports asked for from now on are evidence about it, and
        (a stream from its first command) where the tool stands still, so that the
        program's opening move, from wherever the tool was, is placeable too."""
        self.stream_started = started = time.monotonic()
        self.stream_origin = None
        link = self.commands.state.link
        if start_line != 0 or link is None:
            return
        try:
            if not self.commands.rules.request_queued:  # a real-time status (grbl): always available
                link.query_status()
            elif not (link.realtime_reports and link.probe_realtime_reports(min(1.0, self.commands.timeout_s))):
                return
        except HardwareError:
            return
        mark = link.position_marks[-1] if link.position_marks else None
        if mark is not None and mark.moving is False and mark.asked_at >= started:
            self.stream_origin = mark.position

    def report_evidence(self, seqs: dict[int, int], start_line: int,
                         exc: Exception) -> ReportEvidence | None:
        """The last real position reported during the stream, before the link failed
        (``hardware.reports``), with the commands acknowledged when it arrived; None when
        there was none."""
        started = self.stream_started
        link = self.commands.state.link
        marks = [m for m in (link.position_marks if link is not None else [])
                 if started is not None and m.asked_at >= started]
        if not marks:
            return None
        mark = marks[-1]
        done = [i for i, seq in seqs.items() if seq is not None and seq <= mark.completed]
        acked = max(done) + 1 if done else start_line
        stopped = self.commands.link.failed_at if isinstance(exc, FirmwareReset) else None
        return ReportEvidence(mark.position, max(acked, start_line), mark.asked_at, stopped,
                              self.stream_origin)

    def locate_resume(self) -> ResumeLocation:
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
        gap = self.interrupted
        assert gap is not None  # resume_line() raised otherwise
        if not self.commands.rules.resets_on_connect and not gap.reset:
            found = ResumeLocation(bound, "line numbers", "the controller kept running and numbering lines")
        else:
            sent = gap.acked_index + len(gap.inflight)
            found = self.locate_by_position(bound, gap.acked_index, sent, gap.total)
            if found.basis == "planner bound" and gap.report is not None:
                found = self.locate_by_report(found, gap.report, sent, gap.total)
        found = self.with_repeats(found, gap.acked_index + len(gap.inflight))
        self.last_resume = found
        return found

    def with_repeats(self, found: ResumeLocation, sent: int) -> ResumeLocation:
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
        commands = self.program or []
        last = min(last, len(commands)) if commands else last
        moves = count_moves(commands[found.start:last]) if commands else last - found.start
        return replace(found, repeats=max(last - found.start, 0), repeat_moves=moves)

    def locate_by_report(self, fallback: ResumeLocation, report: ReportEvidence, sent: int,
                          total: int) -> ResumeLocation:
        """The controller lost its position: place the last position it reported while
        streaming on the program (``hardware.resume.locate_by_report``).  A real position is
        evidence: it is used whether it lies after the bound (fewer repeats) or before it
        (the bound assumed less was held than really was: resume earlier, never skip)."""
        commands = self.program
        if commands is None or len(commands) != total:
            return fallback
        p = self.commands.profile
        blocks = planner_blocks(commands, p.dispense_on, p.dispense_off)
        lo = executed_bound(blocks, report.acked_index, self.grbl.held_moves)
        stopped = report.stopped_at if report.stopped_at is not None else (
            self.connected_at if self.connected_at is not None else time.monotonic())
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

    def locate_by_position(self, bound: int, acked: int, sent: int, total: int) -> ResumeLocation:
        commands = self.program
        fallback = "planner bound"
        if commands is None or len(commands) != total:
            return ResumeLocation(bound, fallback, "the program is not known to this process")
        self.commands.state.claim("busy")
        try:
            if self.commands.rules.position_by_status:
                # an Alarm at boot (homing required) is no evidence either way: a board whose
                # reset zeroed its position reports the origin, refused below
                status = self.commands.link.query_status()
                position = status.wpos or status.mpos
            else:
                report = self.commands.send("M114", self.commands.timeout_s).payload
                position = (tuple(report.axes.get(a, 0.0) for a in "XYZ")
                            if isinstance(report, PositionReport) else None)
        finally:
            self.commands.state.release("idle")
        if position is None:
            return ResumeLocation(bound, fallback, "the controller reported no position")
        x, y, z = (float(v) for v in position[:3])
        position = (x, y, z)
        if all(abs(v) < 1e-9 for v in position):
            return ResumeLocation(bound, fallback, "the controller reports the power-on origin: its position "
                                                   "was lost with the reset")
        p = self.commands.profile
        start = locate_by_position(end_positions(commands, p.dispense_on, p.dispense_off), position, bound,
                                   max(sent, bound), acked=acked)
        where = "(" + ", ".join(f"{v:.3f}" for v in position) + ")"
        if start is None:
            return ResumeLocation(bound, fallback, f"the tool at {where} is not at one place of commands "
                                                   f"{bound}..{max(sent, bound)}")
        return ResumeLocation(start, "position", f"the tool stood at {where}: command {start} is the first "
                                                 "not completed")

    def drain_after_rejection(self, exc: FirmwareError, inflight: deque[tuple[int, PendingCommand]],
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
                outcome = pending.result(self.commands.timeout_s * 10, check=False)
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
