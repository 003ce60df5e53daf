"""Commands in flight and their results (used by ``hardware.link``)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

from .errors import CommandRejected, FirmwareError, HardwareError, LinkError
from .events import FirmwareErrorEvent, ReplyEvent
from .session_types import Command

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


def _shared(name: str) -> property:
    """A field of the session's ``Command`` record, read and written through the pending."""
    return property(lambda self: getattr(self.entry, name),
                     lambda self, value: setattr(self.entry, name, value))


class PendingCommand:
    """A command in flight; ``result()`` blocks until it is answered.  Its protocol state
    is the session's ``Command`` record (``entry``, ``hardware.session_types``); the pending
    adds the waiting.  ``PendingCommand(link, command, line_no, data)`` makes its own
    record (tests, tools); the link wraps the session's with ``entry=``."""

    command = _shared("command")
    line_no = _shared("line_no")
    data = _shared("data")
    internal = _shared("internal")
    t_sent = _shared("t_sent")
    replies = _shared("replies")
    resends = _shared("resends")
    accepted = _shared("accepted")
    sync = _shared("sync")
    marker = _shared("marker")  # grbl $G sent by the link to find lost oks
    seq = _shared("seq")  # completion order (see Link.status_marks)
    error_event = _shared("error_event")

    def __init__(self, link: Any, command: str, line_no: int | None, data: bytes,
                 internal: bool = False, *, entry: Command | None = None) -> None:
        self.link = link
        self.entry = entry if entry is not None else \
            Command(command, line_no, data, internal, t_sent=time.monotonic())
        self.entry.owner = self
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
        assert outcome is not None  # set before _done is
        if check and outcome.status == "error":
            event = outcome.error
            assert event is not None  # an "error" status holds its event
            rejected = isinstance(event, FirmwareErrorEvent) and event.kind == "command"
            raise (CommandRejected if rejected else FirmwareError)(
                f"{self.command!r} failed: {getattr(event, 'message', event.raw)}",
                code=getattr(event, "code", None), command=self.command, reply_lines=outcome.reply_lines)
        return outcome


