"""Serial link to a G-code controller: transport by URL, reader thread, correlation, flow
control, resends, keepalive-aware timeouts, out-of-band emergency stop.

    link = Link.open("mock://bench?dialect=marlin", dialect="marlin", window="windowed")
    result = link.send("M114")          # blocks; CommandResult with reply lines + payload
    pending = link.send_async("G1 X1")  # returns at once; pending.result() blocks
    link.emergency_stop()               # M112 / 0x18, never waits behind the queue
    link.close()

Transport: ``serial.serial_for_url`` — device paths, ``socket://host:port``, ``loop://``
and ``mock://`` (registered lazily by ``hardware.transport.open_port``).

Correlation: replies between two acknowledgements belong to the oldest unacknowledged
command.  Marlin lines are numbered and checksummed (``N<n> cmd*<xor>``); with
``ADVANCED_OK`` each ``ok N<n>`` acknowledges line n and every earlier one (the firmware
processes in order), so dropped or duplicated ``ok``s cannot desynchronise the host.

Flow control: ``pingpong`` keeps one command in flight; ``windowed`` keeps up to
``command_buffer`` numbered lines in flight (Marlin) or fills grbl's ``rx_buffer`` bytes
by character counting (``rx_buffer``; ``Machine`` sets it from grbl's ``[OPT:..,..,N]``).
The link falls back to ping-pong (``link.fallbacks`` says why) when Marlin answers
without ``ok N`` (no ADVANCED_OK) or after repeated Marlin stalls.

Reply handling lives in ``hardware.session.ReplySession``, a pure state machine fed with
``(line, now)`` that returns actions (write, complete, halt...); the link keeps the port,
the reader thread and the lock, and applies the actions in order.  Dialect differences are
the fields of ``hardware.dialects``.

Resends: ``Resend: r`` retransmits lines r.. from a bounded history (``history`` lines);
repeated requests caused by lines already in flight are ignored, and the requested lines
go out one at a time (so stale copies on the wire cannot overflow the RX buffer).  A
stall (no acknowledgement for ``poke_s``, default 2.5 s: longer than Marlin's 2 s busy
keepalive; use ~0.02 s against a mock with ``time_scale=0``) pokes the firmware: Marlin
gets the oldest unacknowledged lines again (line numbers make that safe: an accepted line
is answered with ``Resend: last+1``, and when every line in flight is known accepted a
numbered ``M114`` collects the missing ``ok N``), grbl gets ``?`` (it answers even while
dwelling or homing: a sign of life) and one ``$G`` marker once its buffer surely has
room; grbl answers in order, so the marker's ``[GC:...]`` proves every earlier line was
answered and their lost ``ok``s are taken as received (status ``assumed``).  Pokes back
off but never wait longer than ``timeout_s / 3``.  Busy keepalives (``echo:busy``) and
every parsed reply (not line noise) count as life; ``timeout_s`` of silence with commands in flight raises
``LinkError``.  A start banner after the first answer means the controller restarted:
commands in flight fail with ``FirmwareReset`` and the link refuses further sends.

grbl resets itself after ``$C`` leaves check mode and after a homing alarm: the link
expects that banner and sends nothing until it came.

Limits, honestly: grbl has no line numbers or checksums: a line damaged on the wire is
the parser's ``error:1``/``2`` (reported, never re-sent) or, worse, a different valid
line; a lost ``ok`` shifts the replies of the lines sent meanwhile to their neighbours
until the ``$G`` marker resynchronises.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

import serial

from .console_log import ConsoleLog
from .dialects import DEFAULT_DIALECT
from .dialects import dialect as dialect_rules
from .errors import FirmwareError, HardwareError, InvalidConfig, LinkError, ProtocolError
from .events import ReplyEvent, StatusReport
from .pending import CommandResult, PendingCommand
from .protocol import normalize_command
from .reports import PositionMark
from .session import WINDOWS, ReplySession
from .session_types import Action, Complete, Halt, Observed, Write
from .transport import open_port

__all__ = ["WINDOWS", "CommandResult", "Link", "PendingCommand"]


class Link:
    """A connection to one controller; see the module docstring.  Thread-safe."""

    def __init__(self, port: serial.SerialBase, *, dialect: str, timeout_s: float, window: str,
                 history: int, command_buffer: int, rx_buffer: int, poke_s: float,
                 on_event: Callable[[ReplyEvent], None] | None, console: ConsoleLog | None = None) -> None:
        self.port = port
        self.console = console if console is not None else ConsoleLog()  # what went over the wire
        self.rules = dialect_rules(dialect)  # what this firmware does (hardware.dialects)
        self.dialect = self.rules.name
        self.on_event = on_event
        self.session = ReplySession(self.rules, now=time.monotonic(), window=window,
                                    timeout_s=timeout_s, history=history,
                                    command_buffer=command_buffer, rx_buffer=rx_buffer,
                                    poke_s=poke_s)
        self._cond = threading.Condition()
        self._closed = False
        self._halted = False  # the session failed: not one more byte of the program goes out
        self._reader = threading.Thread(target=self._read_loop, daemon=True, name="link-reader")
        self._reader.start()

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(cls, url: str, *, baudrate: int = 115200, dialect: str = DEFAULT_DIALECT,
             timeout_s: float = 30.0, window: str = "windowed", history: int = 1024,
             command_buffer: int = 4, rx_buffer: int = 128, poke_s: float = 2.5,
             on_event: Callable[[ReplyEvent], None] | None = None,
             console: ConsoleLog | None = None) -> Link:
        """Open ``url`` and start the reader.  ``InvalidConfig`` for bad arguments,
        ``LinkError`` when the port cannot be opened.

        ``command_buffer``/``rx_buffer``: the controller's command slots (Marlin BUFSIZE)
        and receive buffer in bytes, the windowed limits.  ``on_event(event)`` sees every
        parsed reply on the reader thread with the link locked: keep it quick and never
        call the link from it.  ``console``: the log the link records every line in (the
        machine's, so that it outlives a reconnect; a new one when not given)."""
        dialect_rules(dialect)
        if window not in WINDOWS:
            raise InvalidConfig(f"unknown window mode {window!r}; expected pingpong or windowed",
                                field="window", value=str(window)[:40])
        if not isinstance(url, str) or not url.strip():
            raise InvalidConfig("port URL is empty", field="port", value=url)
        if timeout_s <= 0 or poke_s <= 0 or history < 16 or command_buffer < 1 or rx_buffer < 16:
            raise InvalidConfig("timeout_s, history, command_buffer or rx_buffer out of range",
                                field="link", value=[timeout_s, history, command_buffer, rx_buffer])
        try:
            # exclusive: a device is one machine; a second opener (another record, another
            # process) is refused instead of interleaving its bytes (POSIX flock)
            port = open_port(url, baudrate=baudrate, timeout=0.01, write_timeout=5,
                             exclusive=True)
        except InvalidConfig:
            raise
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"cannot open port {url!r}: {exc}", field="port", value=url[:80]) from exc
        return cls(port, dialect=dialect, timeout_s=timeout_s, window=window, history=history,
                   command_buffer=command_buffer, rx_buffer=rx_buffer, poke_s=poke_s,
                   on_event=on_event, console=console)

    # ------------------------------------------------------------------ the session's state
    @property
    def timeout_s(self) -> float:
        return self.session.timeout_s

    @property
    def window(self) -> str:
        return self.session.window

    @property
    def mode(self) -> str:
        """``pingpong`` or ``windowed`` (after a fallback: ``pingpong``, see ``fallbacks``)."""
        return self.session.mode

    @property
    def fallbacks(self) -> list[str]:
        return self.session.fallbacks

    @property
    def stats(self) -> dict[str, int]:
        return self.session.stats

    @property
    def unsolicited(self) -> deque[ReplyEvent]:
        return self.session.unsolicited

    @property
    def rx_buffer(self) -> int:
        return self.session.rx_buffer

    @property
    def status_marks(self) -> deque[tuple[StatusReport, int, float]]:
        """grbl status reports with the completion count when they arrived and their time."""
        return self.session.status_marks

    @property
    def position_marks(self) -> deque[PositionMark]:
        return self.session.reports.marks

    @property
    def report_interval_s(self) -> float:
        return self.session.reports.interval_s

    @report_interval_s.setter
    def report_interval_s(self, value: float) -> None:
        with self._cond:
            self.session.reports.interval_s = value

    @property
    def realtime_reports(self) -> bool:
        return self.session.reports.realtime

    @property
    def failed_at(self) -> float | None:
        """Host time the link became fatal, or None."""
        return self.session.failed_at

    @property
    def advanced_ok(self) -> bool:
        """The firmware acknowledges with ``ok N<n>`` (Marlin ADVANCED_OK)."""
        return self.session.n_ok

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
            nbytes = self.rules.line_bytes(text)
            if nbytes > self.session.rx_buffer - 1:
                raise InvalidConfig(f"line longer than the controller's {self.session.rx_buffer}-byte "
                                    "buffer", field="command", value=text[:60])
            self._wait_window(nbytes)
            return self._submit(text)

    def _wait_window(self, nbytes: int) -> None:
        while not self.session.window_open(nbytes, time.monotonic()):
            self._check_fatal()
            self._cond.wait(0.05)
        self._check_fatal()

    def wait_room(self, command: str) -> None:
        """Block until ``command`` would be sent at once (window open), without sending:
        a streamer checks the answers so far before committing the next line."""
        text = normalize_command(command) or ""
        with self._cond:
            self._wait_window(self.rules.line_bytes(text))

    def set_rx_buffer(self, size: int) -> None:
        """Use the receive-buffer size the controller reported (grbl ``[OPT:..,..,N]``)."""
        if size >= 16:
            with self._cond:
                self.session.rx_buffer = size

    def _submit(self, text: str, *, internal: bool = False, sync: bool = False) -> PendingCommand:
        entry, actions = self.session.submit(text, time.monotonic(), internal=internal, sync=sync)
        pending = PendingCommand(self, text, entry.line_no, entry.data, internal, entry=entry)
        self._apply(actions)
        return pending

    # ------------------------------------------------------------------ applying actions
    def _apply(self, actions: list[Action]) -> None:
        """Carry out the session's actions in order (the lock is held)."""
        for action in actions:
            if isinstance(action, Write):
                self._write(action.data)
            elif isinstance(action, Observed):
                if self.on_event is not None:
                    try:
                        self.on_event(action.event)
                    except Exception:  # an observer must never break the link
                        pass
            elif isinstance(action, Complete):
                if action.command.owner is not None:
                    action.command.owner.finish(action.status, action.error)
            elif isinstance(action, Halt):
                if self.session.fatal is not None:
                    self._halted = True
                for command in action.commands:
                    if command.owner is not None:
                        command.owner.fail(action.error)
                self._cond.notify_all()

    def _write(self, data: bytes) -> None:
        if self._halted:
            return
        self.console.record_bytes("sent", data)
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            self._write_failed(exc)

    def _write_failed(self, exc: Exception) -> None:
        """The port died under a write.  Replies the device sent before that may still be
        buffered: let the reader drain them (it fails the link when the port is empty), so
        that every acknowledgement the firmware managed to send is counted."""
        if threading.current_thread() is not self._reader:
            self._cond.wait_for(lambda: self.session.fatal is not None or not self._reader.is_alive(),
                                timeout=2.0)
            self._apply(self.session.halt(LinkError(f"write failed: {exc}", field="port",
                                                    last_line=self.session.last_acked_line()),
                                          time.monotonic()))

    def emergency_stop(self) -> None:
        """Out of band: the dialect's ``estop_bytes`` (Marlin ``M112`` through its emergency
        parser, grbl soft reset 0x18).  Every command in flight fails with ``FirmwareError``.

        Terminal: under the link's lock the session first fails (every later write, program
        line, resend, poke or report, is refused by ``_write``, which checks it under the
        same lock), then the stop bytes are written, so not one byte of the program follows
        them on the wire.  Sent whatever state the link is in (the firmware decides); only a
        dead port makes it fail (``LinkError``).  Reconnect to talk to the machine again."""
        data = self.rules.estop_bytes
        with self._cond:
            self._apply(self.session.halt(FirmwareError("emergency stop", command="emergency_stop"),
                                          time.monotonic()))
            self._halted = True
            self.session.stats["emergency_stops"] = self.session.stats.get("emergency_stops", 0) + 1
            self.console.record("sent", f"EMERGENCY STOP {data!r}")
            try:
                self.port.write(data)
            except (serial.SerialException, OSError) as exc:
                raise LinkError(f"emergency stop could not be written: {exc}", field="port") from exc

    def realtime(self, byte: bytes) -> None:
        """Write a grbl real-time byte (``?``, ``!``, ``~``) outside the queue (refused,
        like every write, once the link failed or was emergency-stopped)."""
        with self._cond:
            self._check_fatal()
            self.console.record_bytes("sent", byte)
            try:
                self.port.write(byte)
            except (serial.SerialException, OSError) as exc:
                raise LinkError(f"write failed: {exc}", field="port") from exc

    def reset_line_numbers(self, next_line: int = 1) -> CommandResult | None:
        """Marlin: ``M110 N<next_line-1>`` so numbering restarts (no-op without line numbers)."""
        if not self.rules.line_numbers:
            return None
        with self._cond:
            while self.session.outstanding and self.session.fatal is None:
                self._cond.wait(0.05)
            self.session.next_line = next_line - 1
            pending = self._submit(f"M110 N{next_line - 1}")
        return pending.result()

    def sync_line_number(self, expected_next: int) -> int:
        """Marlin, after a reconnect without reset: ask which line the firmware accepted
        last.  Sends ``N<expected_next> M114``; returns the last line accepted *before*
        it (so lines up to the returned number will run) and continues numbering after
        whatever the firmware holds.  ``FirmwareReset`` if the firmware restarted."""
        with self._cond:
            while self.session.outstanding and self.session.fatal is None:
                self._cond.wait(0.05)
            self._check_fatal()
            self.session.next_line = expected_next
            pending = self._submit("M114", internal=True, sync=True)
        outcome = pending.result(self.timeout_s)
        if outcome.line_no is None:
            raise ProtocolError("the line-number query came back without a line number",
                                field="line_no")
        return outcome.line_no - 1

    # ------------------------------------------------------------------ reader
    def _handle(self, line: str) -> None:
        """One received line (the lock is held)."""
        self.console.record("received", line.rstrip("\r\n"))
        self._apply(self.session.feed(line, time.monotonic()))

    def _read_loop(self) -> None:
        buf = b""
        while not self._closed:
            try:
                waiting = self.port.in_waiting
                data = self.port.read(waiting or 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._closed:
                    with self._cond:
                        self._apply(self.session.halt(
                            LinkError(f"device disconnected: {exc}", field="port",
                                      last_line=self.session.last_acked_line()), time.monotonic()))
                return
            if data:
                buf += data
                if b"\n" in buf:
                    *lines, buf = buf.split(b"\n")
                    with self._cond:
                        for line in lines:
                            self._handle(line.decode("utf-8", errors="replace"))
                        self._cond.notify_all()
                with self._cond:
                    self._poll_reports()
            else:
                with self._cond:
                    self._apply(self.session.timeout(time.monotonic()))
                    self._poll_reports()

    def _poll_reports(self) -> None:
        if not self._closed:
            self._apply(self.session.poll_reports(time.monotonic()))

    def last_acked_line(self) -> int | None:
        """Highest line number acknowledged as processed (Marlin), else None."""
        return self.session.last_acked_line()

    def query_status(self, timeout_s: float = 2.0, repeat_s: float = 0.25) -> StatusReport:
        """grbl: write ``?`` and wait for the next status report, asking again every
        ``repeat_s`` (a bootloader swallows what arrives while it runs; ``?`` is real-time,
        so an extra one only brings an extra report)."""
        with self._cond:
            seen = self.session.status_seq
            start = time.monotonic()
            self._apply(self.session.ask_status(start))
            asked = start
            while self.session.status_seq == seen:
                self._check_fatal()
                now = time.monotonic()
                if now - start > timeout_s:
                    raise LinkError("no status report", field="timeout_s")
                if now - asked > repeat_s:
                    self._apply(self.session.ask_status(now))
                    asked = now
                self._cond.wait(0.05)
            return self.session.last_status  # type: ignore[return-value]

    def probe_realtime_reports(self, timeout_s: float = 1.0) -> bool:
        """Marlin, idle, after ``M115``: send one ``S000`` and wait for its answer and its
        ``ok``; True when the firmware answered with a position (REALTIME_REPORTING_COMMANDS,
        ``hardware.reports``).  A firmware without it answers ``Unknown command`` and ``ok``."""
        if not self.rules.request_queued:
            return False
        reports = self.session.reports
        with self._cond:
            self._check_fatal()
            before = reports.reported
            self._apply(self.session.ask_queued_report(time.monotonic()))
            deadline = time.monotonic() + timeout_s
            while (reports.rt_pending > 0 or reports.reported == before) and time.monotonic() < deadline:
                self._check_fatal()
                if reports.rt_pending == 0 and reports.reported == before:
                    break  # acknowledged without an answer: not supported
                self._cond.wait(0.02)
            reports.realtime = reports.reported > before
            return reports.realtime

    # ------------------------------------------------------------------ misc
    @property
    def in_flight(self) -> int:
        """Commands sent and not yet answered."""
        return len(self.session.outstanding)

    def wait_idle(self, timeout_s: float | None = None) -> None:
        """Block until nothing is in flight (raises the link's failure)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while self.session.outstanding:
                self._check_fatal()
                if deadline is not None and time.monotonic() > deadline:
                    raise LinkError("commands still in flight", field="timeout_s")
                self._cond.wait(0.05)
            self._check_fatal()

    @property
    def healthy(self) -> bool:
        return self.session.fatal is None and not self._closed

    def close(self) -> None:
        """Stop the reader and close the port (commands in flight fail)."""
        with self._cond:
            self._closed = True
            self._apply(self.session.close(LinkError("link closed", field="port")))
        try:
            self.port.close()
        except (serial.SerialException, OSError):
            pass
        if threading.current_thread() is not self._reader:
            self._reader.join(timeout=1.0)

    def _check_fatal(self) -> None:
        fatal: HardwareError | None = self.session.fatal
        if fatal is not None:
            raise fatal
        if self._closed:
            raise LinkError("link is closed", field="port")
