"""Programs on the serial machine: :class:`ProgramStream` sends a program's commands over the
link, windowed (every answer seen before the next line), with pause (a gate the sending loop
waits at, plus grbl's feed hold), resume and cancel from any thread, and records what is
known executed when the link fails or the controller rejects a line (an ``InterruptedProgram``
in the machine state, which ``ResumeHelper`` reads and refines).
Built with the machine's ``SerialCommands``, its ``ResumeHelper`` and its program clock."""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable

from .errors import FirmwareError, FirmwareReset, HardwareError, LinkError
from .link import PendingCommand
from .machine_args import program_commands
from .machine_host import SerialCommands
from .machine_resume import ResumeHelper
from .machine_state import InterruptedProgram
from .machine_types import StreamReport
from .program_clock import ProgramClock

__all__ = ["REPORT_INTERVAL_S", "ProgramStream"]

REPORT_INTERVAL_S = 0.1  # while streaming: a real-position report this often (hardware.reports)


class ProgramStream:
    """Streams programs and controls the running one (see the module docstring)."""

    def __init__(self, commands: SerialCommands, resumer: ResumeHelper, clock: ProgramClock) -> None:
        self.commands = commands
        self.resumer = resumer
        self.clock = clock
        self.gate = threading.Event()  # cleared while paused: the sending loop waits here
        self.gate.set()
        self.acked_line_no: int | None = None  # firmware line number of the last acknowledged command

    def open_gate(self) -> None:
        """Let a paused sending loop go on (it stops at once when cancelled)."""
        self.gate.set()

    def stream(self, lines: Iterable[str], on_progress: Callable[[int, int], None] | None = None,
               start_line: int = 0) -> StreamReport:
        """Send a program (comments/blank lines dropped) from command ``start_line``.
        ``InvalidConfig`` (field ``program``) when a line is not G-code.

        Returns when every command is acknowledged, or when cancelled (after the commands
        in flight were answered).  On ``LinkError`` the machine remembers what is known to
        be executed (see ``resume_line``) and re-raises."""
        c, st, r = self.commands, self.commands.state, self.resumer
        commands = program_commands(lines, start_line)
        total = len(commands)
        c.claim_motion("printing", "start a program")
        st.program_started(start_line, total)
        self.gate.set()
        r.last_resume = None  # located for the program interrupted before this one
        link = c.link
        started = time.monotonic()
        inflight: deque[tuple[int, PendingCommand]] = deque()
        executed = start_line
        acked_line: int | None = None
        self.clock.start(start_line)
        seqs: dict[int, int] = {}  # command index -> completion order (Link.status_marks)
        r.note_stream_start(start_line)  # where the tool stands, for reports (hardware.reports)
        try:
            r.replay_modes(commands, start_line)
        except HardwareError as exc:
            if isinstance(exc, LinkError):  # nothing of the program was sent: it resumes where it was to start
                st.interrupted = InterruptedProgram(total, start_line, None, [], True, start_line)
                r.program = list(commands)
            st.release("error" if not link.healthy else "idle")
            raise

        def retire_oldest() -> None:
            """Wait for the oldest in-flight command (its LinkError propagates, leaving it
            in flight) and count it as executed."""
            nonlocal executed, acked_line
            index_done, pending = inflight[0]
            outcome = pending.result()
            inflight.popleft()
            seqs[index_done] = pending.seq
            executed, acked_line = index_done + 1, outcome.line_no
            st.progress = (executed, total)
            self.acked_line_no = acked_line
            if on_progress is not None:
                on_progress(executed, total)

        if not c.rules.request_queued or link.realtime_reports:
            link.report_interval_s = REPORT_INTERVAL_S  # the reader asks; the stream never waits for it
        try:
            for index in range(start_line, total):
                link.wait_room(commands[index])  # see every answer before the next line
                while inflight and inflight[0][1].done():
                    retire_oldest()
                if not self.gate.is_set():
                    st.current = "paused"
                    self.gate.wait()
                    st.current = "printing"
                if st.cancel_requested:
                    break
                inflight.append((index, link.send_async(commands[index])))
            while inflight:
                retire_oldest()
            if not self.gate.is_set() and not st.cancel_requested:  # paused after its last line went out:
                st.current = "paused"  # the program holds there until resumed (the pause is not lost)
                self.gate.wait()
                st.current = "printing"
        except LinkError as exc:
            while inflight and inflight[0][1].done() and inflight[0][1].failure is None \
                    and (answer := inflight[0][1].outcome) is not None and answer.status != "error":
                index_done, pending = inflight.popleft()  # answered before the failure
                executed, acked_line = index_done + 1, answer.line_no
                seqs[index_done] = pending.seq
            st.progress = (executed, total)
            st.interrupted = InterruptedProgram(total, executed, acked_line,
                                                [(p.line_no, i) for i, p in inflight],
                                                isinstance(exc, FirmwareReset),
                                                r.moved_bound(commands, executed, seqs),
                                                report=r.report_evidence(seqs, start_line, exc))
            st.release("error")
            exc.resume_line = executed  # lower bound; resume_line() refines it
            raise
        except FirmwareError as exc:
            executed = r.drain_after_rejection(exc, inflight, executed)
            st.progress = (executed, total)
            st.interrupted = InterruptedProgram(total, executed, acked_line, [], False, executed)
            st.release("error" if not link.healthy or st.estopped else "idle")
            raise
        except HardwareError:
            st.interrupted = InterruptedProgram(total, executed, acked_line, [], True)
            st.release("error" if not link.healthy or st.estopped else "idle")
            raise
        finally:
            link.report_interval_s = 0.0
        cancelled = st.cancel_requested
        st.release("idle")
        return StreamReport(executed, total, start_line, cancelled, time.monotonic() - started,
                            dict(link.stats))

    def pause(self) -> None:
        """Stop sending program lines (commands already sent still run)."""
        c, st = self.commands, self.commands.state
        st.require(("printing",), "cannot pause")
        self.gate.clear()
        self.clock.pause()
        if c.rules.feed_hold is not None and st.link is not None:
            st.link.realtime(c.rules.feed_hold)  # feed hold: motion already planned stops too
        st.current = "paused"

    def resume(self) -> None:
        """Continue a paused program."""
        c, st = self.commands, self.commands.state
        st.require(("paused",), "cannot resume")
        if c.rules.cycle_start is not None and st.link is not None:
            st.link.realtime(c.rules.cycle_start)  # cycle start after the feed hold
        st.current = "printing"
        self.clock.resume()
        self.gate.set()

    def cancel(self) -> None:
        """End the program after the commands in flight (no emergency stop)."""
        st = self.commands.state
        st.require(("printing", "paused"), "no program to cancel")
        st.cancel_requested = True
        self.gate.set()

