"""A machine's console: every line the host sent and every line the controller answered, in
order, in a bounded ring a technician can read while a program runs.

    log = ConsoleLog(capacity=4000)
    log.record("sent", "N12 G1 X10*85")
    page = log.since(after=0, limit=200)    # entries with seq > 0, oldest first
    page.entries[-1].text, page.last_seq, page.dropped

Sequence numbers grow by one per line and never repeat for one log, so a reader that asks
``since(after=last_seq)`` again gets exactly what came after, and ``dropped`` says how many
lines the ring forgot between its two reads (it holds ``capacity`` lines; a 115200-baud
stream writes ~1,000 lines/s, so a reader polling once a second with the default capacity
loses none).  Thread-safe: the link's writer, its reader thread and the API read it at once.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Literal

Direction = Literal["sent", "received"]
DEFAULT_CAPACITY = 4000
MAX_TEXT = 240  # characters kept of one line (a runaway reply is cut, not stored whole)


@dataclass(frozen=True)
class ConsoleEntry:
    """One line: ``seq`` (1, 2, ...), ``t`` (Unix time, s), who wrote it, and its text
    without the line ending."""
    seq: int
    t: float
    direction: Direction
    text: str


@dataclass(frozen=True)
class ConsolePage:
    """What ``since`` returns: ``entries`` oldest first, ``last_seq`` to pass as the next
    ``after`` (the newest seq looked at, or ``after`` when nothing matched), ``dropped``: lines
    after ``after`` the ring no longer holds."""
    entries: list[ConsoleEntry]
    last_seq: int
    dropped: int


class ConsoleLog:
    """The bounded ring of a connection's console lines; see the module docstring."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._lines: deque[ConsoleEntry] = deque(maxlen=capacity)
        self._seq = 0
        self._lock = threading.Lock()

    @property
    def last_seq(self) -> int:
        """The seq of the newest line (0 before the first)."""
        return self._seq

    def record(self, direction: Direction, text: str) -> None:
        """Append one line (``text`` without its line ending)."""
        with self._lock:
            self._seq += 1
            self._lines.append(ConsoleEntry(self._seq, time.time(), direction, text[:MAX_TEXT]))

    def record_bytes(self, direction: Direction, data: bytes) -> None:
        """Append each line of ``data`` as written on the wire; a realtime byte (grbl ``?``,
        ``!``, ``~``, 0x18) is kept as its printable name."""
        text = data.decode("ascii", "replace")
        lines = [part.strip() for part in text.splitlines()] or [repr(text)]
        for line in lines:
            if line:
                self.record(direction, line if line.isprintable() else repr(line))

    def since(self, after: int = 0, limit: int = 500, direction: Direction | None = None,
              contains: str | None = None) -> ConsolePage:
        """Up to ``limit`` lines with ``seq > after``, oldest first, optionally only one
        ``direction`` and only lines containing ``contains`` (case-insensitive)."""
        needle = contains.lower() if contains else None
        with self._lock:
            held = list(self._lines)
        first_held = held[0].seq if held else self._seq + 1
        dropped = max(0, first_held - after - 1) if after < first_held else 0
        out: list[ConsoleEntry] = []
        last = after
        for entry in held:
            if entry.seq <= after:
                continue
            last = entry.seq
            if direction is not None and entry.direction != direction:
                continue
            if needle is not None and needle not in entry.text.lower():
                continue
            out.append(entry)
            if len(out) >= limit:
                break
        return ConsolePage(out, last, dropped)
