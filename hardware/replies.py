"""Reply handling of ``hardware.link.Link``: acknowledgements, resend requests and
replays, command errors, alarms, restarts, grbl status, stalls and failures.

A mixin so that the link module stays readable; every method runs with the link's
condition held (the reader thread, or a sender inside ``Link``)."""

from __future__ import annotations

import time
from collections import deque

from .errors import FirmwareError, FirmwareReset, HardwareError, LinkError, ProtocolError
from .events import (Alarm, Busy, Feedback, FirmwareErrorEvent, Halted, Message, Ok,
                     ReplyEvent, Resend, StartBanner, StatusReport, Unknown)
from .protocol import parse_reply


class ReplyHandling:
    """Mixin: the reader side of the link (state lives in ``Link.__init__``)."""

    def _handle(self, line: str) -> None:
        event = parse_reply(line, self.rules.name)
        now = time.monotonic()
        if not isinstance(event, Unknown):  # noise and echoes are no sign of life
            self._last_rx = now
        if self._fatal is not None:  # a dead session: listen, never act
            self.unsolicited.append(event)
            return
        if self.on_event is not None:
            try:
                self.on_event(event)
            except Exception:  # an observer must never break the link
                pass
        if self.rules.request_queued and self._on_position_line(event):
            return  # the S_XYZ line after an S000 answer (hardware.reports)
        if isinstance(event, (Ok, Resend, FirmwareErrorEvent)):
            self._answered = True
        swallow, self._swallow = self._swallow, False
        if isinstance(event, Ok):
            self._on_ok(event, now, swallow)
        elif isinstance(event, Resend):
            self._on_resend(event.line)
        elif isinstance(event, Busy):
            self._last_ack = now
            if self._outstanding:
                self._outstanding[0].replies.append(event)
        elif isinstance(event, FirmwareErrorEvent) and event.is_transmission:
            pass  # the Resend that follows does the work
        elif isinstance(event, FirmwareErrorEvent) and event.kind == "halted" or isinstance(event, Halted):
            self._set_fatal(FirmwareError(f"firmware halted: {event.raw}"))
        elif isinstance(event, FirmwareErrorEvent):
            self._on_command_error(event, now)
        elif isinstance(event, Alarm):
            self._on_alarm(event)
        elif isinstance(event, StartBanner):
            self._on_banner(event)
        elif isinstance(event, StatusReport):
            self._on_status(event)
        elif self.rules.parser_marker and isinstance(event, Feedback) and event.tag == "GC":
            self._on_parser_state(event)
        elif self._outstanding:
            if isinstance(event, Message) and self.rules.announced_resets:
                self._expect_reset_after(event)
            self._outstanding[0].replies.append(event)
        elif event.raw.strip():
            self.unsolicited.append(event)

    def _complete_head(self, status: str, now: float, error: ReplyEvent | None = None) -> None:
        pending = self._outstanding.popleft()
        if pending.error_event is not None and status == "ok":
            status, error = "error", pending.error_event
        self._completed += 1
        pending.seq = self._completed
        pending.finish(status, error)
        if self._replay_inflight is not None and pending.line_no is not None \
                and pending.line_no >= self._replay_inflight:
            self._replay_inflight = None  # the replayed line is through: send the next
            self._pump_replay()
        self._rtt = 0.9 * self._rtt + 0.1 * max(now - pending.t_sent, 1e-5)
        self._last_ack = now
        self._last_answer = now
        self._pokes_in_row = 0

    def _on_ok(self, event: Ok, now: float, swallow: bool = False) -> None:
        if event.line is not None:
            self._n_ok = True
            while self._outstanding and self._outstanding[0].line_no is not None \
                    and self._outstanding[0].line_no <= event.line:
                if self._outstanding[0].line_no == event.line:
                    self._outstanding[0].replies.append(event)
                self._complete_head("ok", now)
            if self._replay_inflight is not None and event.line >= self._replay_inflight:
                self._replay_inflight = None
                self._pump_replay()
            return
        if swallow:  # Marlin 1.x/2.1 follow "Resend: n" with an ok (2.0.x does not)
            return
        if self.rules.request_queued:
            self._on_plain_ok(event.extra)
        if not self._outstanding:
            self.unsolicited.append(event)
            return
        if self.rules.line_numbers and self._n_ok and self._outstanding[0].command != "M105":
            return  # stray plain ok while the firmware speaks ADVANCED_OK
        if self.rules.line_numbers and not self._n_ok and self.mode == "windowed" \
                and len(self._outstanding) > 1:
            self._fallback("firmware acknowledges without line numbers (no ADVANCED_OK)")
        self._outstanding[0].replies.append(event)
        self._complete_head("ok", now)

    def _on_resend(self, line: int) -> None:
        self._swallow = True
        self._rt_pending = 0  # Marlin flushed its receive buffer, S000 lines with it (hardware.reports)
        head = self._outstanding[0] if self._outstanding else None
        if head is not None and head.sync:
            # sync probe answered "Line Number is not Last Line Number+1": adopt the number
            self._outstanding.popleft()
            head.line_no = line
            head.finish("ok")
            self._next_line = line
            return
        now = time.monotonic()
        for pending in self._outstanding:
            if pending.line_no is not None and pending.line_no < line:
                pending.accepted = True
        if not self._n_ok:  # no ok N will ever confirm them: accepted is all we learn
            while self._outstanding and self._outstanding[0].accepted:
                self._complete_head("ok", now)
        if line >= self._next_line:
            if line > self._next_line:
                self._next_line = line
            if self._outstanding and all(p.accepted for p in self._outstanding) \
                    and not any(p.internal for p in self._outstanding):
                self._transmit_new("M114", internal=True)  # its ok N confirms them all
            return
        if self._guard is not None and self._guard[0] == line and self._guard[1] > 0:
            self._guard[1] -= 1  # a line already in flight repeats the same request
            self.stats["ignored_resends"] += 1
            return
        if line not in self._history:
            self._set_fatal(ProtocolError(f"firmware asked to resend line {line}, which is no "
                                          "longer in the history", field="history", value=line))
            return
        self._guard = [line, self._next_line - 1 - line]
        self._replay = deque(range(line, self._next_line))
        self._replay_inflight = None
        self._pump_replay()

    def _pump_replay(self) -> None:
        """Retransmit the lines the firmware asked for, one at a time (ping-pong while
        recovering, so stale copies still on the wire cannot overflow its RX buffer)."""
        while self._replay and self._replay_inflight is None:
            number = self._replay.popleft()
            pending = self._history.get(number)
            if pending is None:
                self._set_fatal(ProtocolError(f"line {number} to resend is no longer in the "
                                              "history", field="history", value=number))
                return
            if pending.outcome is not None:
                continue  # acknowledged already: the request was spurious for this line
            pending.resends += 1
            self.stats["resends"] += 1
            self._replay_inflight = number
            self._write(pending.data)

    def _on_command_error(self, event: FirmwareErrorEvent, now: float) -> None:
        if not self._outstanding:
            self.unsolicited.append(event)
            return
        head = self._outstanding[0]
        head.replies.append(event)
        if self.rules.ok_after_error:
            head.error_event = event  # Marlin still sends ok for this command
            return
        # grbl answers every line once, in order: a rejected line desynchronises nothing.
        # error:1/2 are the parser's verdict on the line as received: never re-sent.
        self._complete_head("error", now, event)

    def _on_alarm(self, event: Alarm) -> None:
        """grbl alarm: the running command fails (its ``ok`` still follows for probe
        alarms); later lines are refused with ``error:9`` by the firmware itself."""
        if self._outstanding:
            head = self._outstanding[0]
            head.replies.append(event)
            head.error_event = event
            if event.code in (6, 7, 8, 9) and head.command.upper().startswith("$H"):
                self._expect_banner_until = time.monotonic() + 5.0  # grbl resets itself
        else:
            self.unsolicited.append(event)

    def _on_banner(self, event: StartBanner) -> None:
        self._next_line = 1
        self._swallow = False
        self._guard = None
        self._replay.clear()
        self._replay_inflight = None
        if self._expect_banner_until is not None:  # the reset grbl announced ($C, homing)
            self._expect_banner_until = None
            self.unsolicited.append(event)
            return
        if self._outstanding and self._answered:  # a restart, not the boot banner of open()
            # poison the link: nothing may be sent into the new session
            self._set_fatal(FirmwareReset("the controller restarted with commands in flight",
                                          last_line=self.last_acked_line()))
        self.unsolicited.append(event)

    def _on_status(self, event: StatusReport) -> None:
        self._status_seq += 1
        self._last_status = event
        self.unsolicited.append(event)
        # which commands were answered when grbl made this report (see Link.status_marks)
        self.status_marks.append((event, self._completed, time.monotonic()))
        self._on_status_position(event)
        # No lost-ok inference here: grbl reports Idle with an empty RX buffer while it
        # dwells, so only the $G marker (below) proves that answers were lost.

    def _expect_reset_after(self, event: Message) -> None:
        """``[MSG:Disabled]`` answers a ``$C`` that leaves check mode: grbl resets next."""
        head = self._outstanding[0]
        if event.text.strip() == "Disabled" and head.command.upper().replace(" ", "") == "$C":
            self._expect_banner_until = time.monotonic() + 5.0

    def _on_parser_state(self, event: ReplyEvent) -> None:
        """grbl prints ``[GC:...]`` when it executes a ``$G``; it answers in order, so every
        command sent before the oldest outstanding ``$G`` was answered: their lost oks
        are taken as received (status ``assumed``)."""
        marker = next((p for p in self._outstanding if not _has_parser_state(p)
                       and p.command.upper().replace(" ", "") == self.rules.parser_marker), None)
        now = time.monotonic()
        while marker is not None and self._outstanding and self._outstanding[0] is not marker:
            self.stats["assumed_ok"] += 1
            error = self._outstanding[0].error_event
            self._complete_head("error" if error else "assumed", now, error)
        if marker is not None:
            marker.replies.append(event)

    def _grbl_poke(self, now: float) -> None:
        """A stalled grbl link: ask for a status (a sign of life; grbl answers ``?`` even
        while dwelling or homing) and, when its receive buffer surely has room, send one
        ``$G`` marker whose ``[GC:]`` answer settles any lost ``ok``."""
        self._note_ask()
        self._write(b"?")
        if any(p.marker and not _has_parser_state(p) for p in self._outstanding) \
                or self._fatal is not None:  # one unanswered marker at a time
            return
        in_flight = sum(len(p.data) for p in self._outstanding)
        room = in_flight + 3 <= self.rx_buffer - 1
        if not room and self.status_marks:
            status, _, seen_at = self.status_marks[-1]
            free = status.fields.get("Bf", "")
            if "," in free:
                room = int(free.split(",")[1]) >= 3
            elif status.state.split(":")[0] in ("Idle", "Alarm", "Check"):
                # not moving and not parsing: after every outstanding dwell has surely
                # ended, nothing can be left unread in its buffer
                room = now - self._last_answer > self._dwell_budget_s() + 4 * self._poke_s \
                    and seen_at > self._last_answer
        if room:
            marker = self._transmit_new(self.rules.parser_marker, internal=True)
            marker.marker = True

    def _dwell_budget_s(self) -> float:
        """Seconds of ``G4`` dwell among the outstanding commands (grbl P is seconds)."""
        total = 0.0
        for pending in self._outstanding:
            words = pending.command.upper().replace(" ", "")
            if words.startswith("G4P"):
                try:
                    total += float(words[3:])
                except ValueError:
                    total += 60.0
        return total

    # ------------------------------------------------------------------ stalls / failures
    def _check_stall(self) -> None:
        if not self._outstanding or self._fatal is not None:
            return
        now = time.monotonic()
        if now - self._last_rx > self.timeout_s:
            self._set_fatal(LinkError(f"no reply for {self.timeout_s} s", field="timeout_s",
                                      last_line=self.last_acked_line()))
            return
        limit = max(self._poke_s, min(20 * self._rtt, 2.0)) * (2 ** min(self._pokes_in_row, 5))
        limit = min(limit, max(self.timeout_s / 3, self._poke_s))  # a sign of life in time
        if now - self._last_ack < limit:
            return
        self._last_ack = now
        self._pokes_in_row += 1
        self.stats["pokes"] += 1
        if self._pokes_in_row >= 3 and self.mode == "windowed" and self.rules.line_numbers:
            self._fallback("repeated stalls")
        if self.rules.parser_marker is not None:
            self._grbl_poke(now)
            return
        if all(p.accepted for p in self._outstanding):
            self._transmit_new("M114", internal=True)
        else:  # replay from the oldest unanswered line (line numbers make this safe)
            self._replay = deque(p.line_no for p in self._outstanding if not p.accepted)
            self._replay_inflight = None
            self._pump_replay()

    def _fallback(self, reason: str) -> None:
        if self.mode != "pingpong":
            self.mode = "pingpong"
            self.fallbacks.append(reason)

    def _fail_all(self, failure: HardwareError) -> None:
        while self._outstanding:
            self._outstanding.popleft().fail(failure)
        self._cond.notify_all()

    def _set_fatal(self, failure: HardwareError) -> None:
        if self._fatal is None:
            self._fatal = failure
            self.failed_at = time.monotonic()
        self._fail_all(failure)

    def _check_fatal(self) -> None:
        if self._fatal is not None:
            raise self._fatal
        if self._closed:
            raise LinkError("link is closed", field="port")


def _has_parser_state(pending: object) -> bool:
    """True once a ``$G`` got its ``[GC:...]`` line (its ``ok`` may still be lost)."""
    return any(isinstance(e, Feedback) and e.tag == "GC" for e in pending.replies)
