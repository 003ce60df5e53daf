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
import re
from typing import Any

from app.domain.errors import InvalidInput
from app.gcode.program_bounds import BoundsScan
from app.gcode.reader import Program
from hardware.protocol import CommandHasher, normalize_block, normalize_command, normalized_commands

# a word, a grbl system command or real-time character, or a tape mark ("%", which
# gcodetools and Fusion-style posts write around a program)
_WORD = re.compile(r"^([GMTFSXYZEIJKOPRNABC]\s*[-+]?\.?\d|\$[A-Z#$]?|[~!?]$|%\s*$)", re.IGNORECASE)
#: a line of normalised commands (each ending "\n") that ``_WORD`` refuses
_NOT_A_COMMAND = re.compile(r"^(?=[^\n])(?![GMTFSXYZEIJKOPRNABC][ \t]*[-+]?\.?\d|\$|[~!?]$|%[ \t]*$)",
                            re.IGNORECASE | re.MULTILINE)
#: the longest line a program may have (characters; a line is held whole while it is read)
MAX_LINE_CHARS = 1 << 20
_BREAKS = "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029"


def _last_break(text: str) -> int:
    """The index just after the last line break of ``text`` (0 without one)."""
    return max(text.rfind(c) for c in _BREAKS) + 1


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
        self._bounds = BoundsScan(field)

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
        text = self._rest + text
        self._rest = ""
        if "\r\n" in text:
            text = text.replace("\r\n", "\n")
        if not final:
            # an unfinished last line (or a "\r" whose "\n" may follow) waits for the next piece
            cut = _last_break(text[:-1] if text.endswith("\r") else text)
            text, self._rest = text[:cut], text[cut:]
            if len(self._rest) > MAX_LINE_CHARS:
                raise InvalidInput(f"line {self.lines + 1} is longer than {MAX_LINE_CHARS} characters",
                                   field=self.field, value=self.lines + 1)
        if not text:
            return
        first = self.lines + 1
        if not self._commands(text):
            self._command_lines(text)
        if self.read_moves:
            self._bounds.block(text, first)

    def _commands(self, text: str) -> bool:
        """Count, digest and check the lines of ``text`` at once (False: it needs line by line)."""
        commands = normalize_block(text)
        if commands is None:
            return False
        if self.check:
            bad = _NOT_A_COMMAND.search(commands)
            if bad is not None:
                number = self.hasher.count + commands.count("\n", 0, bad.start()) + 1
                command = commands[bad.start():commands.index("\n", bad.start())]
                raise InvalidInput(f"command {number} is not G-code: {command[:60]!r}", field=self.field,
                                   value=number)
        self.lines += text.count("\n") + (not text.endswith("\n"))
        self.hasher.update_block(commands)
        return True

    def _command_lines(self, text: str) -> None:
        for raw in text.splitlines():
            self.lines += 1
            command = normalize_command(raw)
            if command is None:
                continue
            self.hasher.update(command)
            if self.check and not _WORD.match(command):
                raise InvalidInput(f"command {self.hasher.count} is not G-code: {command[:60]!r}", field=self.field,
                                   value=self.hasher.count)

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
                "bounds": self._bounds.bounds(), "sha256": self.raw.hexdigest(), "bytes": self.size}


def gcode_meta(text: str, program: Program | None = None, *,
               bounds: list[list[float]] | None = None) -> dict:
    """``{lines, commands, commands_sha256, bounds}``; ``bounds``: the lowest and highest
    machine position the program moves to, ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` mm,
    as :func:`app.gcode.reader.read_program` reads it (relative moves, G92, G28 and inches
    included; an arc's exact extent rather than its chords' ends; None when there are no
    moves).  InvalidInput naming the line when a
    number is not finite.  ``program``: ``text`` already read (:func:`read_program` with its
    default options): its bounds are taken, so that the text is not read twice.
    ``bounds``: the writer's own (:meth:`app.gcode.writer.ProgramBuilder.bounds`, the same
    numbers a reader finds), taken as they are: the moves are not read again."""
    known = program is not None or bounds is not None
    scan = ProgramScan(check=False, read_moves=not known)
    scan.feed_text(text)
    meta = scan.result()
    if program is not None:
        extent = program.bounds()
        meta["bounds"] = None if extent is None else extent.tolist()
    elif bounds is not None:
        meta["bounds"] = [list(bounds[0]), list(bounds[1])]
    return {key: meta[key] for key in ("lines", "commands", "commands_sha256", "bounds")}


def check_gcode(text: str, field: str = "file") -> None:
    """Refuse text that is not G-code: no commands, or a command that starts with no G-code word."""
    commands = normalized_commands(text.splitlines())
    if not commands:
        raise InvalidInput("the program has no G-code commands", field=field, value=0)
    for number, command in enumerate(commands, start=1):
        if not _WORD.match(command):
            raise InvalidInput(f"command {number} is not G-code: {command[:60]!r}", field=field, value=number)
