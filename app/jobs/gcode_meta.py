"""Facts about a G-code text, reported for uploaded programs and G-code artifacts.

``commands_sha256`` follows API.md (each command without line number, checksum, comment
and surrounding blanks, empty lines dropped, each followed by ``\\n``) and is computed by
the hardware codec, so the service and the mock firmware's transcript agree by
construction.
"""

from __future__ import annotations

import re

from app.errors import InvalidInput
from app.gcode.reader import Program, read_program
from hardware.protocol import commands_sha256, normalized_commands

_WORD = re.compile(r"^([GMTFSXYZEIJKPRNABC]\s*-?\d|\$[A-Z#$]?|[~!?]$)", re.IGNORECASE)


def gcode_meta(text: str, program: Program | None = None) -> dict:
    """``{lines, commands, commands_sha256, bounds}``; ``bounds``: the lowest and highest
    machine position the program moves to, ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` mm,
    as :func:`app.gcode.reader.read_program` reads it (relative moves, G92, G28, arcs and
    inches included; None when there are no moves).  ``program``: ``text`` already read
    (:func:`read_program` with its default options), so that it is not read twice."""
    lines = text.splitlines()
    digest = commands_sha256(lines)
    extent = (program if program is not None else read_program(text)).bounds()
    bounds = None if extent is None else extent.tolist()
    return {"lines": len(lines), "commands": digest.count, "commands_sha256": digest.sha256, "bounds": bounds}


def check_gcode(text: str, field: str = "file") -> None:
    """Refuse text that is not G-code: no commands, or a command that starts with no G-code word."""
    commands = normalized_commands(text.splitlines())
    if not commands:
        raise InvalidInput("the program has no G-code commands", field=field, value=0)
    for number, command in enumerate(commands, start=1):
        if not _WORD.match(command):
            raise InvalidInput(f"command {number} is not G-code: {command[:60]!r}", field=field, value=number)
