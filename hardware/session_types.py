"""What the reply session (``hardware.session``) works on and what it asks the link to do.

``Command`` is one command the host sent, as the session keeps it (pure data: no event, no
lock, no clock; ``t_sent`` is the ``now`` the session was given).  ``owner`` is opaque to
the session: the link puts its ``PendingCommand`` there, the one that a caller waits on.

Actions, in the order the link must apply them:

* ``Write(data, reason)`` - put ``data`` on the wire (``reason``: ``command`` a new line,
  ``resend`` a line retransmitted after ``Resend:`` or a stall, ``poke`` a status request or
  marker asked by a stall, ``report`` a position request while streaming);
* ``Observed(event)`` - a parsed reply, for the link's ``on_event`` observer;
* ``Complete(command, status, error)`` - the command's answer came: ``status`` ``ok``,
  ``error`` (``error`` holds the event) or ``assumed`` (grbl ``ok`` lost, settled by ``$G``);
* ``Halt(commands, error)`` - the session failed (restart, timeout, halt, resend beyond
  the history, emergency stop, port failure) or was closed: every command in ``commands``
  fails with ``error``; after a failure the session writes nothing more;
* ``Position(mark)`` - a real position was reported (``hardware.reports.PositionMark``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .errors import HardwareError
from .events import Feedback, ReplyEvent


@dataclass(eq=False)
class Command:
    """A command in flight (see module).  ``line_no``: Marlin line number, else None;
    ``data``: the bytes written; ``accepted``: a later ``Resend`` proved the firmware
    took it; ``sync``: an ``N<n> M114`` asking which line the firmware holds; ``marker``:
    a grbl ``$G`` sent to settle lost ``ok``s; ``seq``: completion order; ``status``: the
    answer once complete (None while in flight)."""

    command: str
    line_no: int | None
    data: bytes
    internal: bool = False
    t_sent: float = 0.0
    replies: list[ReplyEvent] = field(default_factory=list)
    resends: int = 0
    accepted: bool = False
    sync: bool = False
    marker: bool = False
    seq: int | None = None
    error_event: ReplyEvent | None = None
    status: str | None = None
    owner: Any = None

    def has_parser_state(self) -> bool:
        """True once a ``$G`` got its ``[GC:...]`` line (its ``ok`` may still be lost)."""
        return any(isinstance(e, Feedback) and e.tag == "GC" for e in self.replies)


@dataclass(frozen=True)
class Write:
    data: bytes
    reason: str = "command"


@dataclass(frozen=True)
class Observed:
    event: ReplyEvent


@dataclass(frozen=True)
class Complete:
    command: Command
    status: str
    error: ReplyEvent | None = None


@dataclass(frozen=True)
class Halt:
    commands: tuple[Command, ...]
    error: HardwareError


@dataclass(frozen=True)
class Position:
    mark: Any  # hardware.reports.PositionMark


Action = Write | Observed | Complete | Halt | Position
