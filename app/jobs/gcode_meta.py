"""Facts about a G-code text, reported for uploaded programs and G-code artifacts.

``commands_sha256`` follows API.md (each command without line number, checksum, comment
and surrounding blanks, empty lines dropped, each followed by ``\\n``) and is computed by
the hardware codec, so the service and the mock firmware's transcript agree by
construction.

:class:`ProgramScan` reads a program piece by piece (an upload as it is copied): its memory
is one piece and the modal state, whatever the number of lines; :func:`gcode_meta` is the
same scan over one text.
"""

from __future__ import annotations

import codecs
import hashlib
import math
import re
from typing import Any

import numpy as np
import numpy.typing as npt

from app.errors import InvalidInput
from app.gcode.lines import GcodeLine, read_lines
from app.gcode.reader import HOME, ModalReader, Program, ReadOptions
from hardware.protocol import CommandHasher, normalize_command, normalized_commands

# a word, a grbl system command or real-time character, or a tape mark ("%", which
# gcodetools and Fusion-style posts write around a program)
_WORD = re.compile(r"^([GMTFSXYZEIJKOPRNABC]\s*[-+]?\.?\d|\$[A-Z#$]?|[~!?]$|%\s*$)", re.IGNORECASE)


class _BoundsReader(ModalReader):
    """The modal reader keeping only the lowest and highest XYZ a non-homing move ends at."""

    def __init__(self, field: str) -> None:
        super().__init__(ReadOptions())
        self.field = field
        self.low = np.full(3, np.inf)
        self.high = np.full(3, -np.inf)

    def line(self, parsed: GcodeLine) -> None:
        for letter, value in parsed.words:
            if not math.isfinite(value):
                raise InvalidInput(f"line {parsed.number}: {letter} is not a finite number", field=self.field,
                                   value={"line": parsed.number, "text": parsed.text.strip()[:80]})
        super().line(parsed)

    def emit(self, start: npt.NDArray[np.float64], end: npt.NDArray[np.float64], motion: int, number: int,
             extrudes: bool) -> None:
        if motion != HOME:
            np.minimum(self.low, end[:3], out=self.low)
            np.maximum(self.high, end[:3], out=self.high)
        self.state.stop_pending = False

    def bounds(self) -> list[list[float]] | None:
        if not np.isfinite(self.low).all():
            return None
        return [self.low.tolist(), self.high.tolist()]


class ProgramScan:
    """``feed(bytes)`` piece by piece, then :meth:`result`: lines, commands, their digest and
    bounds (see :func:`gcode_meta`), and the sha256 and size of the bytes.  ``check``: refuse
    what is not G-code (:func:`check_gcode`'s rules) as it comes."""

    def __init__(self, *, field: str = "file", check: bool = True, read_moves: bool = True) -> None:
        self.field = field
        self.check = check
        self.read_moves = read_moves  # False: bounds are not read (the caller has them)
        self.lines = 0
        self.size = 0
        self.raw = hashlib.sha256()
        self.hasher = CommandHasher()
        self._decoder = codecs.getincrementaldecoder("utf-8")()
        self._rest = ""
        self._reader = _BoundsReader(field)

    def feed(self, data: bytes) -> None:
        self.raw.update(data)
        try:
            text = self._decoder.decode(data)
        except UnicodeDecodeError as exc:
            at = self.size + exc.start
            raise InvalidInput(f"the file is not UTF-8 text (byte {at})", field=self.field, value=at) from None
        finally:
            self.size += len(data)
        self._text(text, final=False)

    def feed_text(self, text: str) -> None:
        """Feed decoded text (its bytes are not hashed)."""
        self._text(text, final=False)

    def _text(self, text: str, final: bool) -> None:
        pieces = (self._rest + text).splitlines(keepends=True)
        self._rest = ""
        # an unfinished last line (or a "\r" whose "\n" may follow) waits for the next piece
        if not final and pieces and (pieces[-1].endswith("\r") or pieces[-1].splitlines()[0] == pieces[-1]):
            self._rest = pieces.pop()
        block = "".join(pieces)
        offset = self.lines
        for raw in block.splitlines():
            self.lines += 1
            command = normalize_command(raw)
            if command is None:
                continue
            self.hasher.update(command)
            if self.check and not _WORD.match(command):
                raise InvalidInput(f"command {self.hasher.count} is not G-code: {command[:60]!r}", field=self.field,
                                   value=self.hasher.count)
        if self.read_moves:
            for parsed in read_lines(block, strict=False):
                self._reader.line(parsed._replace(number=parsed.number + offset))

    def result(self) -> dict[str, Any]:
        """``{lines, commands, commands_sha256, bounds, sha256, bytes}`` of everything fed."""
        try:
            tail = self._decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            raise InvalidInput(f"the file is not UTF-8 text (byte {self.size})", field=self.field,
                               value=self.size) from None
        self._text(tail, final=True)
        digest = self.hasher.digest()
        if self.check and digest.count == 0:
            raise InvalidInput("the program has no G-code commands", field=self.field, value=0)
        return {"lines": self.lines, "commands": digest.count, "commands_sha256": digest.sha256,
                "bounds": self._reader.bounds(), "sha256": self.raw.hexdigest(), "bytes": self.size}


def gcode_meta(text: str, program: Program | None = None) -> dict:
    """``{lines, commands, commands_sha256, bounds}``; ``bounds``: the lowest and highest
    machine position the program moves to, ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` mm,
    as :func:`app.gcode.reader.read_program` reads it (relative moves, G92, G28, arcs and
    inches included; None when there are no moves).  InvalidInput naming the line when a
    number is not finite.  ``program``: ``text`` already read (:func:`read_program` with its
    default options): its bounds are taken, so that the text is not read twice."""
    scan = ProgramScan(check=False, read_moves=program is None)
    scan.feed_text(text)
    meta = scan.result()
    if program is not None:
        extent = program.bounds()
        meta["bounds"] = None if extent is None else extent.tolist()
    return {key: meta[key] for key in ("lines", "commands", "commands_sha256", "bounds")}


def check_gcode(text: str, field: str = "file") -> None:
    """Refuse text that is not G-code: no commands, or a command that starts with no G-code word."""
    commands = normalized_commands(text.splitlines())
    if not commands:
        raise InvalidInput("the program has no G-code commands", field=field, value=0)
    for number, command in enumerate(commands, start=1):
        if not _WORD.match(command):
            raise InvalidInput(f"command {number} is not G-code: {command[:60]!r}", field=field, value=number)
