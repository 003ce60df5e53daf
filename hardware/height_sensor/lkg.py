"""The Keyence LK-G series RS-232C command format (pure codec, no I/O).

What this follows (LK-G series user manual, chapter 5 "RS-232C"): commands and responses are
ASCII delimited by CR; upper or lower case; one command at a time (the host waits for the
response before the next); a response echoes the main command as its header; a refused
command answers ``ER,<main command>,<code>`` with code 00 command error, 01 status error,
20 command length error, 21 parameter count error, 22 invalid parameter, 88 timeout,
99 other.  A measurement value is a fixed 8-character field: a sign and 7 characters with
the decimal point, right-aligned (``+01.2345``, ``-00.0120``); ``+FFFFFFF`` / ``-FFFFFFF``
over the measuring range, ``XXXXXXXX`` when no value could be measured (alarm: too little
or too much light).

The subset Conforma speaks (and the mock answers):

* ``Q0`` / ``R0``: to communication mode (settings; measurement stops) and back to general
  mode (measurement); measurement and storage commands in communication mode are a status
  error (``ER,M1,01``);
* ``M0`` / ``M1``: measured value output (OUT1 and OUT2 / OUT1): ``M1,+01.2345``;
* data storage: ``AQ`` initialise, ``AS`` start, ``AP`` stop (each echoed), ``AN`` status
  ``AN,<0 stopped | 1 storing>,<count>``, ``AO,1`` output OUT1's stored values
  ``AO,<v>,<v>,...`` (one per sampling cycle since ``AS``; at most the storage capacity).

The sampling cycle and the head's settings are set on the controller (its keypad or the
setup software); the host is told them in its sensor configuration.  Units: mm.
"""

from __future__ import annotations

import math

CR = b"\r"
WIDTH = 8
OVER = ("+FFFFFFF", "-FFFFFFF")
ALARM = "XXXXXXXX"
ERROR_CODES = {"00": "command error", "01": "status error", "20": "command length error",
               "21": "parameter count error", "22": "invalid parameter", "88": "timeout", "99": "other error"}
DECIMALS = 4  # a +-10 mm head at 0.1 um display resolution: +01.2345


class LkgFormatError(ValueError):
    """A response that is not in the LK-G format."""


def format_value(value_mm: float | None, range_mm: float, decimals: int = DECIMALS) -> str:
    """The 8-character field of one value: None (no measurement) -> ``XXXXXXXX``; beyond
    +-``range_mm`` -> ``+FFFFFFF`` / ``-FFFFFFF``; else sign and 7 characters."""
    if value_mm is None or not math.isfinite(value_mm):
        return ALARM
    if abs(value_mm) > range_mm:
        return OVER[0] if value_mm > 0 else OVER[1]
    text = f"{abs(value_mm):0{WIDTH - 1}.{decimals}f}"
    if len(text) != WIDTH - 1:
        raise LkgFormatError(f"{value_mm} does not fit the {WIDTH}-character value format")
    return ("-" if value_mm < 0 and float(text) != 0.0 else "+") + text


def parse_value(field: str) -> float | None:
    """A value field back to mm: None for ``XXXXXXXX`` and ``+-FFFFFFF`` (no valid value);
    ``LkgFormatError`` for anything that is not a value."""
    text = field.strip()
    if text == ALARM or text in OVER:
        return None
    if len(text) != WIDTH or text[0] not in "+-":
        raise LkgFormatError(f"not an LK-G value: {field!r}")
    try:
        return float(text)
    except ValueError:
        raise LkgFormatError(f"not an LK-G value: {field!r}") from None


def parse_values(fields: list[str]) -> tuple[list[float], list[bool]]:
    """Values (n,) mm (NaN where invalid) and their validity (n,) from value fields."""
    values, valid = [], []
    for f in fields:
        v = parse_value(f)
        values.append(math.nan if v is None else v)
        valid.append(v is not None)
    return values, valid


def split_response(line: str) -> tuple[str, list[str]]:
    """``"M1,+01.2345"`` -> ``("M1", ["+01.2345"])``; an error response keeps its header
    ``"ER"`` (its fields: the main command and the code)."""
    parts = line.strip().split(",")
    return parts[0].upper(), parts[1:]


def error_text(fields: list[str]) -> str:
    """The reason of an ``ER`` response's fields (command, code)."""
    command = fields[0] if fields else "?"
    code = fields[1] if len(fields) > 1 else "99"
    return f"{command}: {ERROR_CODES.get(code, 'unknown error')} ({code})"
