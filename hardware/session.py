"""The host side of the G-code conversation as a pure state machine: no port, no thread,
no lock, no clock (every time is the caller's ``now``, ``time.monotonic()`` seconds).

    session = ReplySession(dialect("marlin"), now=0.0)
    command, actions = session.submit("G1 X1", now=0.0)   # [Write(b"N1 G1 X1*..\\n")]
    session.feed("ok N1", now=0.01)                        # [Observed(Ok), Complete(command, "ok")]
    session.timeout(now=3.0)                               # a stall: pokes, or Halt after timeout_s

``hardware.link.Link`` owns the port, the reader thread and the lock and applies the
actions (``hardware.session_types``) in order.  What the session decides (see the link's
module docstring for the protocol): correlation of replies to the oldest unacknowledged
command, Marlin ``ok N`` covering every earlier line, resends replayed one at a time,
command errors (Marlin still sends ``ok``; grbl's ``error:N`` is the answer), alarms and the
controller's own state (``hardware.controller_state``), restarts (a banner flushes the
host's markers; after the first answer it fails every command in flight), stalls (Marlin
replays or sends ``M114``; grbl ``?`` and a ``$G`` marker whose ``[GC:]`` settles lost
``ok``s), the fallback to ping-pong and the windowed flow control (``window_open``).
"""

from __future__ import annotations

from collections import OrderedDict, deque

from . import events as ev
from .controller_state import ControllerState, next_controller_state
from .dialects import Dialect
from .errors import FirmwareError, FirmwareReset, HardwareError, LinkError, ProtocolError
from .protocol import dwell_budget_s, frame, parse_reply
from .reports import PositionMark, PositionTracker
from .session_types import Action, Command, Complete, Halt, Observed, Position, Write

WINDOWS = ("pingpong", "windowed")
RESET_BANNER_WAIT_S = 5.0  # how long an announced grbl reset may take to show its banner


class ReplySession:
    """See the module docstring.  ``window``: ``pingpong`` or ``windowed``; ``history``:
    numbered lines kept for resends; ``command_buffer``/``rx_buffer``: the controller's
    command slots and receive bytes; ``poke_s``: the first stall poke (s); ``timeout_s``:
    silence with commands in flight that fails the session (s)."""

    def __init__(self, rules: Dialect, *, now: float, window: str = "windowed",
                 timeout_s: float = 30.0, history: int = 1024, command_buffer: int = 4,
                 rx_buffer: int = 128, poke_s: float = 2.5) -> None:
        self.rules = rules
        self.timeout_s = timeout_s
        self.window = window
        self.mode = window
        self.history_size = history
        self.command_buffer = command_buffer
        self.rx_buffer = rx_buffer
        self.poke_s = poke_s
        self.fallbacks: list[str] = []  # why the link fell back to ping-pong
        self.stats = {"sent": 0, "resends": 0, "pokes": 0, "ignored_resends": 0, "assumed_ok": 0, "retries": 0}
        self.unsolicited: deque[ev.ReplyEvent] = deque(maxlen=200)
        self.outstanding: deque[Command] = deque()
        self.history: OrderedDict[int, Command] = OrderedDict()
        self.next_line = 1
        self.n_ok = False  # the firmware answers "ok N<n>" (ADVANCED_OK)
        self.fatal: HardwareError | None = None
        self.failed_at: float | None = None  # the now at which the session failed
        self.status_seq = 0
        self.last_status: ev.StatusReport | None = None
        self.status_marks: deque[tuple[ev.StatusReport, int, float]] = deque(maxlen=64)
        self.controller: ControllerState | None = None  # the firmware's own state (grbl)
        self.completed = 0  # commands answered so far (Command.seq)
        self._swallow = False  # the plain ok right after a Resend belongs to the request
        self._guard: list[int] | None = None
        self._replay: deque[int] = deque()
        self._replay_inflight: int | None = None  # the resend being replayed
        self._answered = False  # a first answer came (a later banner is a restart)
        self._last_rx = self._waiting_since = self._last_ack = self._last_answer = now  # sign of life, wait, ack
        self._rtt, self._pokes_in_row = 0.002, 0
        self._expect_banner_until: float | None = None
        self._actions: list[Action] = []
        self.reports = PositionTracker(rules)

    # ------------------------------------------------------------------ actions
    def _take(self) -> list[Action]:
        actions, self._actions = self._actions, []
        return actions

    def _write(self, data: bytes, reason: str = "command") -> None:
        if self.fatal is None:  # a failed session writes nothing (the stop stays last)
            self._actions.append(Write(data, reason))

    def _fail(self, failure: HardwareError, now: float) -> None:
        if self.fatal is None:
            self.fatal = failure
            self.failed_at = now
        self._drop(failure)

    def _drop(self, failure: HardwareError) -> None:
        dropped = tuple(self.outstanding)
        self.outstanding.clear()
        for command in dropped:
            command.status = "failed"
        self._actions.append(Halt(dropped, failure))

    # ------------------------------------------------------------------ sending
    def submit(self, text: str, now: float, *, internal: bool = False, sync: bool = False
               ) -> tuple[Command, list[Action]]:
        """Number (Marlin) and send the normalised command ``text``; the caller checked
        ``window_open``.  ``sync``: the firmware's ``Resend`` answer gives the line it
        holds (``Link.sync_line_number``)."""
        command = self._send(text, now, internal=internal, sync=sync)
        return command, self._take()

    def _send(self, text: str, now: float, *, internal: bool = False, sync: bool = False
              ) -> Command:
        if self.rules.line_numbers:
            line_no: int | None = self.next_line
            self.next_line += 1
            data = (frame(line_no, text) + "\n").encode("utf-8")  # type: ignore[arg-type]
        else:
            line_no = None
            data = (text + "\n").encode("utf-8")
        command = Command(text, line_no, data, internal, t_sent=now, sync=sync)
        if not self.outstanding:
            self._last_ack = now
            self._waiting_since = now  # an idle firmware owed nothing until now
        self.outstanding.append(command)
        if line_no is not None:
            self.history[line_no] = command
            while len(self.history) > self.history_size:
                self.history.popitem(last=False)
        self.stats["sent"] += 1
        self._write(data)
        return command

    def window_open(self, nbytes: int, now: float) -> bool:
        """True when a line of ``nbytes`` (``rules.line_bytes``) may be sent now (always
        once the session failed: the sender then sees the failure)."""
        if self.fatal is not None:
            return True
        if self.awaiting_reset(now):
            return False  # grbl announced a reset: what we sent now would be lost
        if self._replay or self._replay_inflight is not None:
            return False  # recovering from a resend request
        outstanding = self.outstanding
        if not outstanding:
            return True
        if self.mode == "pingpong":
            return False
        in_flight = sum(len(p.data) for p in outstanding)
        if self.rules.window == "bytes":  # grbl: character counting
            return in_flight + nbytes <= self.rx_buffer - 1
        # Marlin: free command slots, and never more bytes than its RX buffer holds (it
        # stops reading serial while a command blocks, e.g. on a full planner)
        return len(outstanding) < self.command_buffer \
            and in_flight + nbytes + self.reports.reserved_bytes() <= self.rx_buffer - 1

    def awaiting_reset(self, now: float) -> bool:
        """True while a reset the firmware announced has not shown its banner yet."""
        until = self._expect_banner_until
        if until is not None and now > until:
            self._expect_banner_until = until = None  # it never came: carry on
        return until is not None

    def halt(self, failure: HardwareError, now: float) -> list[Action]:
        """Fail the session (emergency stop, port failure): all in flight fail, nothing is written."""
        self._fail(failure, now)
        return self._take()

    def close(self, failure: HardwareError) -> list[Action]:
        """The link closes: commands in flight fail with ``failure``."""
        self._drop(failure)
        return self._take()

    def last_acked_line(self) -> int | None:
        """Highest line number acknowledged as processed (Marlin), else None."""
        best = None
        for command in self.history.values():
            if command.status is not None and command.status not in ("error", "failed"):
                best = command.line_no
        return best

    # ------------------------------------------------------------------ replies
    # one flat dispatch over cases; splitting it hides their order
    def feed(self, line: str, now: float) -> list[Action]:  # noqa: C901
        """One reply line (terminator optional) received at ``now``."""
        event = parse_reply(line, self.rules.name)
        kind = type(event).__name__
        if self.rules.proves_alive(kind):  # Dialect.alive_replies: never noise or echoes
            self._last_rx = now
        if self.fatal is not None:  # a dead session: listen, never act
            self.unsolicited.append(event)
            return self._take()
        self._actions.append(Observed(event))
        if self.rules.request_queued:
            head = self.outstanding[0].replies if self.outstanding else None
            consumed, mark = self.reports.on_position_line(event, now, head, self.completed)
            self._positioned(mark)
            if consumed:
                return self._take()  # the S_XYZ line after an S000 answer (hardware.reports)
        if isinstance(event, (ev.Ok, ev.Resend, ev.FirmwareErrorEvent)) and self.outstanding:
            self._answered = True  # an answer to a command (a fresh grbl's error:7 at boot is none)
        if self.rules.position_by_status:  # the firmware's own state (Marlin reports none)
            self.controller = next_controller_state(self.controller, event, now, self.rules.lock_error)
        swallow, self._swallow = self._swallow, False
        if isinstance(event, ev.Ok):
            self._on_ok(event, now, swallow)
        elif isinstance(event, ev.Resend):
            self._on_resend(event.line, now)
        elif self.rules.says_busy(kind):  # the command in hand still runs: no stall poke
            self._last_ack = now
            if self.outstanding:
                self.outstanding[0].replies.append(event)
        elif isinstance(event, ev.FirmwareErrorEvent) and event.is_transmission:
            pass  # the Resend that follows does the work
        elif isinstance(event, ev.FirmwareErrorEvent) and event.kind == "halted" or isinstance(event, ev.Halted):
            self._fail(FirmwareError(f"firmware halted: {event.raw}"), now)
        elif isinstance(event, ev.FirmwareErrorEvent):
            self._on_command_error(event, now)
        elif isinstance(event, ev.Alarm):
            self._on_alarm(event, now)
        elif isinstance(event, ev.StartBanner):
            self._on_banner(event, now)
        elif isinstance(event, ev.StatusReport):
            self._on_status(event, now)
        elif self.rules.parser_marker and isinstance(event, ev.Feedback) and event.tag == "GC":
            self._on_parser_state(event, now)
        elif self.outstanding:
            if isinstance(event, ev.Message) and self.rules.announced_resets:
                self._expect_reset_after(event, now)
            self.outstanding[0].replies.append(event)
        elif event.raw.strip():
            self.unsolicited.append(event)
        return self._take()

    def _complete_head(self, status: str, now: float, error: ev.ReplyEvent | None = None) -> None:
        command = self.outstanding.popleft()
        if command.error_event is not None and status == "ok":
            status, error = "error", command.error_event
        self.completed += 1
        command.seq = self.completed
        command.status = status
        self._actions.append(Complete(command, status, error))
        if self._replay_inflight is not None and command.line_no is not None \
                and command.line_no >= self._replay_inflight:
            self._replay_inflight = None  # the replayed line is through: send the next
            self._pump_replay(now)
        self._rtt = 0.9 * self._rtt + 0.1 * max(now - command.t_sent, 1e-5)
        self._last_ack = now
        self._last_answer = now
        self._pokes_in_row = 0

    def _on_ok(self, event: ev.Ok, now: float, swallow: bool = False) -> None:
        if event.line is not None:
            self.n_ok = True
            while self.outstanding and self.outstanding[0].line_no is not None \
                    and self.outstanding[0].line_no <= event.line:
                if self.outstanding[0].line_no == event.line:
                    self.outstanding[0].replies.append(event)
                self._complete_head("ok", now)
            if self._replay_inflight is not None and event.line >= self._replay_inflight:
                self._replay_inflight = None
                self._pump_replay(now)
            return
        if swallow:  # Marlin 1.x/2.1 follow "Resend: n" with an ok (2.0.x does not)
            return
        if self.rules.request_queued:
            self.reports.on_plain_ok(event.extra)
        if not self.outstanding:
            self.unsolicited.append(event)
            return
        if self.rules.line_numbers and self.n_ok and self.outstanding[0].command != "M105":
            return  # stray plain ok while the firmware speaks ADVANCED_OK
        if self.rules.line_numbers and not self.n_ok and self.mode == "windowed" \
                and len(self.outstanding) > 1:
            self._fallback("firmware acknowledges without line numbers (no ADVANCED_OK)")
        self.outstanding[0].replies.append(event)
        self._complete_head("ok", now)

    def _on_resend(self, line: int, now: float) -> None:
        self._swallow = True
        self.reports.flushed()
        head = self.outstanding[0] if self.outstanding else None
        if head is not None and head.sync:
            # sync probe answered "Line Number is not Last Line Number+1": adopt the number
            self.outstanding.popleft()
            head.line_no = line
            head.status = "ok"
            self._actions.append(Complete(head, "ok"))
            self.next_line = line
            return
        for command in self.outstanding:
            if command.line_no is not None and command.line_no < line:
                command.accepted = True
        if not self.n_ok:  # no ok N will ever confirm them: accepted is all we learn
            while self.outstanding and self.outstanding[0].accepted:
                self._complete_head("ok", now)
        if line >= self.next_line:
            if line > self.next_line:
                self.next_line = line
            if self.outstanding and all(p.accepted for p in self.outstanding) \
                    and not any(p.internal for p in self.outstanding):
                self._send("M114", now, internal=True)  # its ok N confirms them all
            return
        if self._guard is not None and self._guard[0] == line and self._guard[1] > 0:
            self._guard[1] -= 1  # a line already in flight repeats the same request
            self.stats["ignored_resends"] += 1
            return
        if line not in self.history:
            self._fail(ProtocolError(f"firmware asked to resend line {line}, which is no "
                                     "longer in the history", field="history", value=line), now)
            return
        self._guard = [line, self.next_line - 1 - line]
        self._replay = deque(range(line, self.next_line))
        self._replay_inflight = None
        self._pump_replay(now)

    def _pump_replay(self, now: float) -> None:
        """Retransmit the lines the firmware asked for, one at a time (ping-pong while
        recovering, so stale copies still on the wire cannot overflow its RX buffer)."""
        while self._replay and self._replay_inflight is None:
            number = self._replay.popleft()
            command = self.history.get(number)
            if command is None:
                self._fail(ProtocolError(f"line {number} to resend is no longer in the "
                                         "history", field="history", value=number), now)
                return
            if command.status is not None:
                continue  # acknowledged already: the request was spurious for this line
            command.resends += 1
            self.stats["resends"] += 1
            self._replay_inflight = number
            self._write(command.data, "resend")

    def _on_command_error(self, event: ev.FirmwareErrorEvent, now: float) -> None:
        if not self.outstanding:
            self.unsolicited.append(event)
            return
        head = self.outstanding[0]
        head.replies.append(event)
        if self.rules.ok_after_error:
            head.error_event = event  # Marlin still sends ok for this command
            return
        # grbl answers every line once, in order: a rejected line desynchronises nothing.
        # error:1/2 are the parser's verdict on the line as received: never re-sent.
        self._complete_head("error", now, event)

    def _on_alarm(self, event: ev.Alarm, now: float) -> None:
        """grbl alarm: the running command fails (its ``ok`` still follows for probe
        alarms); later lines are refused with ``error:9`` by the firmware itself."""
        if self.outstanding:
            head = self.outstanding[0]
            head.replies.append(event)
            head.error_event = event
            if event.code in (6, 7, 8, 9) and head.command.upper().startswith("$H"):
                self._expect_banner_until = now + RESET_BANNER_WAIT_S  # grbl resets itself
        else:
            self.unsolicited.append(event)

    def _on_banner(self, event: ev.StartBanner, now: float) -> None:
        """The controller (re)started and flushed its receive buffer: the host's own markers
        are forgotten (never matched to a later reply); an announced reset fails what is
        still in flight, an unannounced one after the first answer fails the session."""
        self.next_line = 1
        self._swallow = False
        self._guard = None
        self._replay.clear()
        self._replay_inflight = None
        self.reports.flushed()
        own = tuple(c for c in self.outstanding if c.internal)
        self.outstanding = deque(c for c in self.outstanding if not c.internal)
        for command in own:
            command.status = "failed"
        if own:
            self._actions.append(Halt(own, FirmwareReset("the controller reset: the host's own request was flushed")))
        if self._expect_banner_until is not None:  # the reset grbl announced ($C, homing)
            self._expect_banner_until = None
            if self.outstanding:
                self._drop(FirmwareReset("the controller reset itself (announced): the command was "
                                         "flushed with its receive buffer", last_line=self.last_acked_line()))
            self.unsolicited.append(event)
            return
        if self._answered:  # a restart, not open()'s boot banner: it lost units and feed, and may ignore input
            self._fail(FirmwareReset("the controller restarted with commands in flight" if self.outstanding
                                     else "the controller restarted between two commands",
                                     last_line=self.last_acked_line()), now)
        self.unsolicited.append(event)

    def _on_status(self, event: ev.StatusReport, now: float) -> None:
        self.status_seq += 1
        self.last_status = event
        self.unsolicited.append(event)
        # which commands were answered when grbl made this report (see Link.status_marks)
        self.status_marks.append((event, self.completed, now))
        self._positioned(self.reports.on_status(event, now, self.completed))
        # No lost-ok inference here: grbl reports Idle with an empty RX buffer while it
        # dwells, so only the $G marker (below) proves that answers were lost.

    def _expect_reset_after(self, event: ev.Message, now: float) -> None:
        """``[MSG:Disabled]`` answers a ``$C`` that leaves check mode: grbl resets next."""
        head = self.outstanding[0]
        if event.text.strip() == "Disabled" and head.command.upper().replace(" ", "") == "$C":
            self._expect_banner_until = now + RESET_BANNER_WAIT_S

    def _on_parser_state(self, event: ev.ReplyEvent, now: float) -> None:
        """grbl prints ``[GC:...]`` when it executes a ``$G``; it answers in order, so every
        command sent before the oldest outstanding ``$G`` was answered: their lost oks
        are taken as received (status ``assumed``)."""
        marker = next((p for p in self.outstanding if not p.has_parser_state()
                       and p.command.upper().replace(" ", "") == self.rules.parser_marker), None)
        while marker is not None and self.outstanding and self.outstanding[0] is not marker:
            self.stats["assumed_ok"] += 1
            error = self.outstanding[0].error_event
            self._complete_head("error" if error else "assumed", now, error)
        if marker is not None:
            marker.replies.append(event)

    # ------------------------------------------------------------------ position reports
    def _positioned(self, mark: PositionMark | None) -> None:
        if mark is not None:
            self._actions.append(Position(mark))

    def ask_status(self, now: float) -> list[Action]:
        """Ask for one real-time report (grbl ``?``; dialects whose request is not queued)."""
        self._write(self.reports.ask(now), "report")
        return self._take()

    def ask_queued_report(self, now: float) -> list[Action]:
        """Marlin: one ``S000`` (also acknowledged later by a plain ``ok``)."""
        self._write(self.reports.ask(now, queued=True), "report")
        return self._take()

    def poll_reports(self, now: float) -> list[Action]:
        """Reader tick: ask for a position when ``reports.interval_s`` has passed."""
        if self.fatal is None:
            request = self.reports.poll(now, sum(len(p.data) for p in self.outstanding), self.rx_buffer)
            if request is not None:
                self._write(request, "report")
        return self._take()

    # ------------------------------------------------------------------ stalls
    def silent_s(self, now: float) -> float:
        """Seconds the firmware owes an answer without a sign of life (``Dialect.alive_replies``),
        counted from the host's first wait for a firmware silent while idle
        (``Dialect.idle_silent``: that silence is no evidence of a dead link)."""
        return now - (max(self._last_rx, self._waiting_since) if self.rules.idle_silent else self._last_rx)

    def timeout(self, now: float) -> list[Action]:
        """The reader saw nothing: fail after ``timeout_s`` of ``silent_s``; poke a stalled
        firmware (backing off, never later than ``timeout_s / 3``)."""
        if not self.outstanding or self.fatal is not None:
            return self._take()
        if self.silent_s(now) > self.timeout_s:
            self._fail(LinkError(f"no reply for {self.timeout_s} s", field="timeout_s",
                                 last_line=self.last_acked_line()), now)
            return self._take()
        limit = max(self.poke_s, min(20 * self._rtt, 2.0)) * (2 ** min(self._pokes_in_row, 5))
        limit = min(limit, max(self.timeout_s / 3, self.poke_s))  # a sign of life in time
        if now - self._last_ack < limit:
            return self._take()
        self._last_ack = now
        self._pokes_in_row += 1
        self.stats["pokes"] += 1
        if self._pokes_in_row >= 3 and self.mode == "windowed" and self.rules.line_numbers:
            self._fallback("repeated stalls")
        if self.rules.parser_marker is not None:
            self._marker_poke(now)
        elif all(p.accepted for p in self.outstanding):
            self._send("M114", now, internal=True)
        else:  # replay from the oldest unanswered line (line numbers make this safe)
            self._replay = deque(p.line_no for p in self.outstanding if not p.accepted)  # type: ignore[misc]
            self._replay_inflight = None
            self._pump_replay(now)
        return self._take()

    def _marker_poke(self, now: float) -> None:
        """A stalled grbl link: ask for a status (a sign of life; grbl answers ``?`` even
        while dwelling or homing) and, when its receive buffer surely has room, send one
        ``$G`` marker whose ``[GC:]`` answer settles any lost ``ok``."""
        if (query := self.rules.life_query) is not None:  # answered in any state
            self._write(self.reports.ask(now) if query == self.rules.position_request else query, "poke")
        if any(p.marker and not p.has_parser_state() for p in self.outstanding) \
                or self.fatal is not None:  # one unanswered marker at a time
            return
        marker_text = self.rules.parser_marker or ""
        in_flight = sum(len(p.data) for p in self.outstanding)
        room = in_flight + len(marker_text) + 1 <= self.rx_buffer - 1
        if not room and self.status_marks:
            status, _, seen_at = self.status_marks[-1]
            free = status.fields.get("Bf", "")
            if "," in free:
                room = int(free.split(",")[1]) >= len(marker_text) + 1
            elif status.state.split(":")[0] in ("Idle", "Alarm", "Check"):
                # not moving and not parsing: after every outstanding dwell has surely
                # ended, nothing can be left unread in its buffer
                room = now - self._last_answer > dwell_budget_s(p.command for p in self.outstanding) + 4 * self.poke_s \
                    and seen_at > self._last_answer
        if room:
            marker = self._send(marker_text, now, internal=True)
            marker.marker = True

    def _fallback(self, reason: str) -> None:
        if self.mode != "pingpong":
            self.mode = "pingpong"
            self.fallbacks.append(reason)
