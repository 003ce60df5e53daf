"""Serial link to a G-code controller: transport by URL, reader thread, correlation, flow
control, resends, keepalive-aware timeouts, out-of-band emergency stop.

    link = Link.open("mock://bench?dialect=marlin", dialect="marlin", window="windowed")
    result = link.send("M114")          # blocks; CommandResult with reply lines + payload
    pending = link.send_async("G1 X1")  # returns at once; pending.result() blocks
    link.emergency_stop()               # M112 / 0x18, never waits behind the queue
    link.close()

Transport: ``serial.serial_for_url`` — device paths, ``socket://host:port``, ``loop://``
and ``mock://`` (registered by ``hardware.mock``).

Correlation: replies between two acknowledgements belong to the oldest unacknowledged
command.  Marlin lines are numbered and checksummed (``N<n> cmd*<xor>``); with
``ADVANCED_OK`` each ``ok N<n>`` acknowledges line n and every earlier one (the firmware
processes in order), so dropped or duplicated ``ok``s cannot desynchronise the host.

Flow control: ``pingpong`` keeps one command in flight; ``windowed`` keeps up to
``command_buffer`` numbered lines in flight (Marlin) or fills grbl's ``rx_buffer`` bytes
by character counting.  The link falls back to ping-pong (``link.fallbacks`` says why)
when Marlin answers without ``ok N`` (no ADVANCED_OK), when grbl rejects a line, or after
repeated stalls.

Resends: ``Resend: r`` retransmits lines r.. from a bounded history (``history`` lines);
repeated requests caused by lines already in flight are ignored.  A stall (no
acknowledgement for ``poke_s``, adaptive) pokes the firmware: Marlin gets the oldest
unacknowledged line again (its line number makes that safe: an already accepted line is
answered with ``Resend: last+1``), grbl gets ``?`` and, when its status shows an empty RX
buffer and an idle machine, the lost ``ok``s are taken as received.  Busy keepalives
(``echo:busy``) and any other reply count as life; ``timeout_s`` of silence with commands
in flight raises ``LinkError``.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass

import serial

from . import mock as _mock  # noqa: F401  (registers the mock:// handler)
from .errors import (FirmwareError, FirmwareReset, HardwareError, InvalidConfig, LinkError,
                     ProtocolError)
from .events import (Alarm, Busy, FirmwareErrorEvent, Halted, Ok, ReplyEvent, Resend,
                     StartBanner, StatusReport)
from .protocol import check_dialect, frame, normalize_command, parse_reply

WINDOWS = ("pingpong", "windowed")
_PAYLOAD_TYPES = ("ProbeReport", "PositionReport", "FirmwareInfo", "StatusReport",
                  "TemperatureReport")


@dataclass(frozen=True)
class CommandResult:
    """What one command got back.  ``status``: ``ok``, ``error`` (firmware rejected it;
    ``error`` holds the event) or ``assumed`` (grbl ``ok`` lost, inferred from an idle
    status).  Times are ``time.monotonic()`` seconds."""

    command: str
    line_no: int | None
    reply_lines: tuple[str, ...]
    events: tuple[ReplyEvent, ...]
    payload: ReplyEvent | None
    status: str
    error: ReplyEvent | None
    t_sent: float
    t_done: float
    resends: int


class PendingCommand:
    """A command in flight; ``result()`` blocks until it is answered."""

    def __init__(self, link: Link, command: str, line_no: int | None, data: bytes,
                 internal: bool = False) -> None:
        self.link = link
        self.command = command
        self.line_no = line_no
        self.data = data
        self.internal = internal
        self.t_sent = time.monotonic()
        self.replies: list[ReplyEvent] = []
        self.resends = 0
        self.accepted = False
        self.sync = False
        self.error_event: ReplyEvent | None = None
        self.outcome: CommandResult | None = None
        self.failure: HardwareError | None = None
        self._done = threading.Event()

    def done(self) -> bool:
        return self._done.is_set()

    def finish(self, status: str, error: ReplyEvent | None = None) -> None:
        payload = next((e for e in self.replies if type(e).__name__ in _PAYLOAD_TYPES), None)
        self.outcome = CommandResult(self.command, self.line_no,
                                     tuple(e.raw for e in self.replies), tuple(self.replies),
                                     payload, status, error, self.t_sent, time.monotonic(),
                                     self.resends)
        self._done.set()

    def fail(self, failure: HardwareError) -> None:
        self.failure = failure
        self._done.set()

    def result(self, timeout: float | None = None, *, check: bool = True) -> CommandResult:
        """Wait for the answer.  Raises the link's failure (``LinkError``...), or
        ``FirmwareError`` when ``check`` and the firmware rejected the command."""
        if not self._done.wait(timeout):
            raise LinkError(f"no answer to {self.command!r} within {timeout} s",
                            field="command", value=self.command[:60])
        if self.failure is not None:
            raise self.failure
        outcome = self.outcome
        if check and outcome.status == "error":
            event = outcome.error
            raise FirmwareError(f"{self.command!r} failed: {getattr(event, 'message', event.raw)}",
                                code=getattr(event, "code", None), command=self.command)
        return outcome


class Link:
    """A connection to one controller; see the module docstring.  Thread-safe."""

    def __init__(self, port: serial.SerialBase, *, dialect: str, timeout_s: float, window: str,
                 history: int, command_buffer: int, rx_buffer: int,
                 on_event: Callable[[ReplyEvent], None] | None) -> None:
        self.port = port
        self.dialect = dialect
        self.timeout_s = timeout_s
        self.window = window
        self.mode = window
        self.history_size = history
        self.command_buffer = command_buffer
        self.rx_buffer = rx_buffer
        self.on_event = on_event
        self.fallbacks: list[str] = []
        self.stats = {"sent": 0, "resends": 0, "pokes": 0, "ignored_resends": 0,
                      "assumed_ok": 0, "retries": 0}
        self.unsolicited: deque[ReplyEvent] = deque(maxlen=200)
        self._cond = threading.Condition()
        self._outstanding: deque[PendingCommand] = deque()
        self._history: OrderedDict[int, PendingCommand] = OrderedDict()
        self._next_line = 1
        self._swallow = 0
        self._guard: list[int] | None = None
        self._tx = 0
        self._outcomes = 0
        self._n_ok = False
        self._fatal: HardwareError | None = None
        self._status_seq = 0
        self._last_status: StatusReport | None = None
        self._closed = False
        self._last_rx = time.monotonic()
        self._last_ack = time.monotonic()
        self._rtt = 0.002
        self._poke_s = 0.01
        self._pokes_in_row = 0
        self._reader = threading.Thread(target=self._read_loop, daemon=True, name="link-reader")
        self._reader.start()

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(cls, url: str, *, baudrate: int = 115200, dialect: str = "marlin",
             timeout_s: float = 30.0, window: str = "windowed", history: int = 1024,
             command_buffer: int = 4, rx_buffer: int = 128,
             on_event: Callable[[ReplyEvent], None] | None = None) -> Link:
        """Open ``url`` and start the reader.  ``InvalidConfig`` for bad arguments,
        ``LinkError`` when the port cannot be opened."""
        check_dialect(dialect)
        if window not in WINDOWS:
            raise InvalidConfig(f"unknown window mode {window!r}; expected pingpong or windowed",
                                field="window", value=str(window)[:40])
        if not isinstance(url, str) or not url.strip():
            raise InvalidConfig("port URL is empty", field="port", value=url)
        if timeout_s <= 0 or history < 16 or command_buffer < 1 or rx_buffer < 16:
            raise InvalidConfig("timeout_s, history, command_buffer or rx_buffer out of range",
                                field="link", value=[timeout_s, history, command_buffer, rx_buffer])
        try:
            port = serial.serial_for_url(url, baudrate=baudrate, timeout=0.05, write_timeout=5)
        except InvalidConfig:
            raise
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"cannot open port {url!r}: {exc}", field="port", value=url[:80]) from exc
        return cls(port, dialect=dialect, timeout_s=timeout_s, window=window, history=history,
                   command_buffer=command_buffer, rx_buffer=rx_buffer, on_event=on_event)

    # ------------------------------------------------------------------ sending
    def send(self, command: str, timeout_s: float | None = None, *, check: bool = True
             ) -> CommandResult:
        """Send and wait for the answer (see ``PendingCommand.result``)."""
        return self.send_async(command).result(timeout_s, check=check)

    def send_async(self, command: str) -> PendingCommand:
        """Queue ``command`` (raw G-code line; comments are stripped) once the window has
        room and return at once."""
        text = normalize_command(command)
        if text is None:
            raise InvalidConfig("empty command", field="command", value=command[:60])
        with self._cond:
            nbytes = len(text) + 1 if self.dialect == "grbl" else 0
            if nbytes > self.rx_buffer - 1:
                raise InvalidConfig(f"line longer than the controller's {self.rx_buffer}-byte "
                                    "buffer", field="command", value=text[:60])
            while not self._window_open(nbytes):
                self._check_fatal()
                self._cond.wait(0.05)
            self._check_fatal()
            return self._transmit_new(text)

    def _window_open(self, nbytes: int) -> bool:
        if self._fatal is not None:
            return True
        outstanding = self._outstanding
        if not outstanding:
            return True
        if self.mode == "pingpong":
            return False
        if self.dialect == "grbl":
            return sum(len(p.data) for p in outstanding) + nbytes <= self.rx_buffer - 1
        return len(outstanding) < self.command_buffer

    def _transmit_new(self, text: str, internal: bool = False) -> PendingCommand:
        if self.dialect == "marlin":
            line_no = self._next_line
            self._next_line += 1
            data = (frame(line_no, text) + "\n").encode("utf-8")
        else:
            line_no = None
            data = (text + "\n").encode("utf-8")
        pending = PendingCommand(self, text, line_no, data, internal)
        if not self._outstanding:
            self._last_ack = time.monotonic()
        self._outstanding.append(pending)
        if line_no is not None:
            self._history[line_no] = pending
            while len(self._history) > self.history_size:
                self._history.popitem(last=False)
        self.stats["sent"] += 1
        self._write(data)
        return pending

    def _write(self, data: bytes) -> None:
        if self._fatal is not None:
            return
        try:
            self.port.write(data)
            self._tx += 1
        except (serial.SerialException, OSError) as exc:
            self._write_failed(exc)

    def _write_failed(self, exc: Exception) -> None:
        """The port died under a write.  Replies the device sent before that may still be
        buffered: let the reader drain them (it fails the link when the port is empty), so
        that every acknowledgement the firmware managed to send is counted."""
        if threading.current_thread() is not self._reader:
            self._cond.wait_for(lambda: self._fatal is not None or not self._reader.is_alive(),
                                timeout=2.0)
            self._set_fatal(LinkError(f"write failed: {exc}", field="port",
                                      last_line=self.last_acked_line()))

    def emergency_stop(self) -> None:
        """Out of band: Marlin ``M112`` (emergency parser), grbl soft reset 0x18.  Every
        command in flight fails with ``FirmwareError``."""
        data = b"M112\n" if self.dialect == "marlin" else b"\x18"
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"emergency stop could not be written: {exc}", field="port") from exc
        with self._cond:
            self._fail_all(FirmwareError("emergency stop", command="emergency_stop"))

    def realtime(self, byte: bytes) -> None:
        """Write a grbl real-time byte (``?``, ``!``, ``~``) outside the queue."""
        try:
            self.port.write(byte)
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"write failed: {exc}", field="port") from exc

    def reset_line_numbers(self, next_line: int = 1) -> CommandResult | None:
        """Marlin: ``M110 N<next_line-1>`` so numbering restarts (no-op for grbl)."""
        if self.dialect != "marlin":
            return None
        with self._cond:
            while self._outstanding and self._fatal is None:
                self._cond.wait(0.05)
            self._next_line = next_line - 1
            pending = self._transmit_new(f"M110 N{next_line - 1}")
        return pending.result()

    def sync_line_number(self, expected_next: int) -> int:
        """Marlin, after a reconnect without reset: ask which line the firmware accepted
        last.  Sends ``N<expected_next> M114``; returns the last line accepted *before*
        it (so lines up to the returned number will run) and continues numbering after
        whatever the firmware holds.  ``FirmwareReset`` if the firmware restarted."""
        with self._cond:
            while self._outstanding and self._fatal is None:
                self._cond.wait(0.05)
            self._check_fatal()
            self._next_line = expected_next
            pending = self._transmit_new("M114", internal=True)
            pending.sync = True
        outcome = pending.result(self.timeout_s)
        return outcome.line_no - 1

    # ------------------------------------------------------------------ reader
    def _read_loop(self) -> None:
        buf = b""
        while not self._closed:
            try:
                waiting = self.port.in_waiting
                data = self.port.read(waiting or 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._closed:
                    with self._cond:
                        self._set_fatal(LinkError(f"device disconnected: {exc}", field="port",
                                                  last_line=self.last_acked_line()))
                return
            if data:
                buf += data
                if b"\n" in buf:
                    *lines, buf = buf.split(b"\n")
                    with self._cond:
                        for line in lines:
                            self._handle(line.decode("utf-8", errors="replace"))
                        self._cond.notify_all()
            else:
                with self._cond:
                    self._check_stall()

    def last_acked_line(self) -> int | None:
        """Highest line number acknowledged as processed (Marlin), else None."""
        best = None
        for pending in self._history.values():
            if pending.outcome is not None and pending.outcome.status != "error":
                best = pending.line_no
        return best

    def _handle(self, line: str) -> None:
        event = parse_reply(line, self.dialect)
        now = time.monotonic()
        self._last_rx = now
        if self._fatal is not None:  # a dead session: listen, never act
            self.unsolicited.append(event)
            return
        if self.on_event is not None:
            try:
                self.on_event(event)
            except Exception:  # an observer must never break the link
                pass
        if isinstance(event, Ok):
            self._on_ok(event, now)
        elif isinstance(event, Resend):
            self._on_resend(event.line)
        elif isinstance(event, Busy):
            self._last_ack = now
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
        elif self._outstanding:
            self._outstanding[0].replies.append(event)
        elif event.raw.strip():
            self.unsolicited.append(event)

    def _complete_head(self, status: str, now: float, error: ReplyEvent | None = None) -> None:
        pending = self._outstanding.popleft()
        if pending.error_event is not None and status == "ok":
            status, error = "error", pending.error_event
        pending.finish(status, error)
        self._rtt = 0.9 * self._rtt + 0.1 * max(now - pending.t_sent, 1e-5)
        self._last_ack = now
        self._pokes_in_row = 0

    def _on_ok(self, event: Ok, now: float) -> None:
        self._outcomes += 1
        if event.line is not None:
            self._n_ok = True
            while self._outstanding and self._outstanding[0].line_no is not None \
                    and self._outstanding[0].line_no <= event.line:
                if self._outstanding[0].line_no == event.line:
                    self._outstanding[0].replies.append(event)
                self._complete_head("ok", now)
            return
        if self._swallow > 0:
            self._swallow -= 1
            return
        if not self._outstanding:
            self.unsolicited.append(event)
            return
        if self.dialect == "marlin" and self._n_ok and self._outstanding[0].command != "M105":
            return  # stray plain ok while the firmware speaks ADVANCED_OK
        if self.dialect == "marlin" and not self._n_ok and self.mode == "windowed" \
                and len(self._outstanding) > 1:
            self._fallback("firmware acknowledges without line numbers (no ADVANCED_OK)")
        self._outstanding[0].replies.append(event)
        self._complete_head("ok", now)

    def _on_resend(self, line: int) -> None:
        self._swallow += 1
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
        for number in range(line, self._next_line):
            pending = self._history.get(number)
            if pending is None:
                break
            pending.resends += 1
            self.stats["resends"] += 1
            self._write(pending.data)

    def _on_command_error(self, event: FirmwareErrorEvent, now: float) -> None:
        if not self._outstanding:
            self.unsolicited.append(event)
            return
        head = self._outstanding[0]
        head.replies.append(event)
        if self.dialect == "marlin":
            head.error_event = event  # Marlin still sends ok for this command
            return
        if self.mode == "windowed" and len(self._outstanding) > 1:
            self._fallback(f"grbl rejected a streamed line ({event.raw})")
        elif event.code in (1, 2) and head.resends < 2 and self.mode == "pingpong":
            head.resends += 1  # damaged line: nothing ran, so sending it again is safe
            self.stats["retries"] += 1
            self._write(head.data)
            return
        self._complete_head("error", now, event)

    def _on_alarm(self, event: Alarm) -> None:
        if self._outstanding:
            head = self._outstanding.popleft()
            head.replies.append(event)
            head.finish("error", event)
        self._fail_all(FirmwareError(f"alarm {event.code}: {event.message}", code=event.code))

    def _on_banner(self, event: StartBanner) -> None:
        self._next_line = 1
        self._swallow = 0
        self._guard = None
        if self._outstanding:  # poison the link: nothing may be sent into the new session
            self._set_fatal(FirmwareReset("the controller restarted with commands in flight",
                                          last_line=self.last_acked_line()))
        self.unsolicited.append(event)

    def query_status(self, timeout_s: float = 2.0) -> StatusReport:
        """grbl: write ``?`` and wait for the next status report."""
        with self._cond:
            seen = self._status_seq
            self._write_raw(b"?")
            deadline = time.monotonic() + timeout_s
            while self._status_seq == seen:
                self._check_fatal()
                if time.monotonic() > deadline:
                    raise LinkError("no status report", field="timeout_s")
                self._cond.wait(0.05)
            return self._last_status

    def _on_status(self, event: StatusReport) -> None:
        self._status_seq += 1
        self._last_status = event
        self.unsolicited.append(event)
        if self.dialect != "grbl" or not self._outstanding:
            return
        free = event.fields.get("Bf", "")
        rx_free = int(free.split(",")[1]) if "," in free else None
        if event.state == "Idle" and rx_free is not None and rx_free >= self.rx_buffer - 1:
            now = time.monotonic()
            while self._outstanding:
                self.stats["assumed_ok"] += 1
                self._complete_head("assumed", now)

    # ------------------------------------------------------------------ stalls / failures
    def _check_stall(self) -> None:
        if not self._outstanding or self._fatal is not None:
            return
        now = time.monotonic()
        if now - self._last_rx > self.timeout_s:
            self._set_fatal(LinkError(f"no reply for {self.timeout_s} s", field="timeout_s",
                                      last_line=self.last_acked_line()))
            return
        limit = min(max(self._poke_s, 20 * self._rtt), 2.0) * (2 ** min(self._pokes_in_row, 5))
        if now - self._last_ack < limit:
            return
        self._last_ack = now
        self._pokes_in_row += 1
        self.stats["pokes"] += 1
        if self._pokes_in_row >= 3 and self.mode == "windowed":
            self._fallback("repeated stalls")
        if self.dialect == "grbl":
            self._write_raw(b"?")
            return
        head = self._outstanding[0]
        if all(p.accepted for p in self._outstanding):
            self._transmit_new("M114", internal=True)
        else:
            head.resends += 1
            self._write(head.data)

    def _write_raw(self, data: bytes) -> None:
        if self._fatal is not None:
            return
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            self._write_failed(exc)

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
        self._fail_all(failure)

    def _check_fatal(self) -> None:
        if self._fatal is not None:
            raise self._fatal
        if self._closed:
            raise LinkError("link is closed", field="port")

    # ------------------------------------------------------------------ misc
    @property
    def in_flight(self) -> int:
        """Commands sent and not yet answered."""
        return len(self._outstanding)

    def wait_idle(self, timeout_s: float | None = None) -> None:
        """Block until nothing is in flight (raises the link's failure)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while self._outstanding:
                self._check_fatal()
                if deadline is not None and time.monotonic() > deadline:
                    raise LinkError("commands still in flight", field="timeout_s")
                self._cond.wait(0.05)
            self._check_fatal()

    @property
    def healthy(self) -> bool:
        return self._fatal is None and not self._closed

    def close(self) -> None:
        """Stop the reader and close the port (commands in flight fail)."""
        with self._cond:
            self._closed = True
            self._fail_all(LinkError("link closed", field="port"))
        try:
            self.port.close()
        except (serial.SerialException, OSError):
            pass
        if threading.current_thread() is not self._reader:
            self._reader.join(timeout=1.0)
