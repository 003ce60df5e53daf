"""Commands in flight and their results (used by ``hardware.link``)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

from .errors import FirmwareError, HardwareError, LinkError
from .events import ReplyEvent

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

    def __init__(self, link: Any, command: str, line_no: int | None, data: bytes,
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
        self.marker = False  # grbl $G sent by the link to find lost oks
        self.seq: int | None = None  # completion order (see Link.status_marks)
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
                                code=getattr(event, "code", None), command=self.command,
                                reply_lines=outcome.reply_lines)
        return outcome


