"""Facts about a G-code text, reported for uploaded programs and G-code artifacts.

``commands_sha256`` follows API.md (each command without line number, checksum, comment
and surrounding blanks, empty lines dropped, each followed by ``\\n``) and is computed by
the hardware codec, so the service and the mock firmware's transcript agree by
construction.
"""

from __future__ import annotations

import re

from app.errors import InvalidInput
from hardware.protocol import commands_sha256, normalized_commands

_WORD = re.compile(r"^([GMTFSXYZEIJKPRNABC]\s*-?\d|\$[A-Z#$]?|[~!?]$)", re.IGNORECASE)
_AXIS = re.compile(r"([XYZ])\s*(-?\d+(?:\.\d*)?|-?\.\d+)", re.IGNORECASE)


def gcode_meta(text: str) -> dict:
    """``{lines, commands, commands_sha256, bounds}``; bounds of absolute G0/G1 X Y Z
    targets in mm as ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (None when no moves)."""
    lines = text.splitlines()
    digest = commands_sha256(lines)
    position: dict[str, float] = {}
    lows: dict[str, float] = {}
    highs: dict[str, float] = {}
    for command in normalized_commands(lines):
        head = command.split(None, 1)[0].upper()
        if head not in ("G0", "G1", "G00", "G01"):
            continue
        for axis, value in _AXIS.findall(command):
            position[axis.upper()] = float(value)
        for axis, value in position.items():
            lows[axis] = min(lows.get(axis, value), value)
            highs[axis] = max(highs.get(axis, value), value)
    bounds = None
    if all(a in lows for a in "XYZ"):
        bounds = [[lows[a] for a in "XYZ"], [highs[a] for a in "XYZ"]]
    return {"lines": len(lines), "commands": digest.count, "commands_sha256": digest.sha256, "bounds": bounds}


def check_gcode(text: str, field: str = "file") -> None:
    """Refuse text that is not G-code: no commands, or a command that starts with no G-code word."""
    commands = normalized_commands(text.splitlines())
    if not commands:
        raise InvalidInput("the program has no G-code commands", field=field, value=0)
    for number, command in enumerate(commands, start=1):
        if not _WORD.match(command):
            raise InvalidInput(f"command {number} is not G-code: {command[:60]!r}", field=field, value=number)
