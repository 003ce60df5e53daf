"""The dispenser's on/off delays written into a program (pure): a dwell after each switch.

A paste dispenser starts flowing some time after its valve opens and keeps flowing some
time after it closes.  A material's dispense profile states both delays; a program written
without them gets, after every line that switches the dispenser on, a ``G4`` dwell of the
on-delay (the head waits while the bead starts) and after every line that switches it off a
dwell of the off-delay (the pressure drops before the travel).  The on/off lines are the
machine's exact commands, compared by their words (``m106  s255`` is ``M106 S255``), as
:mod:`app.gcode.reader` finds them.  Nothing else changes: every other line is kept as it is.
"""

from __future__ import annotations

from dataclasses import dataclass

from app.gcode.lines import read_lines
from app.gcode.writer import DIALECTS

__all__ = ["DelayedProgram", "with_dispense_delays"]


@dataclass(frozen=True)
class DelayedProgram:
    """text: the program with the dwells; on_dwells / off_dwells: how many were added."""

    text: str
    on_dwells: int
    off_dwells: int


def _key(line: str) -> str:
    parsed = read_lines(line, strict=False)
    if not parsed:
        return ""
    return " ".join(f"{letter}{value:g}" for letter, value in parsed[0].words if letter != "N")


def with_dispense_delays(text: str, dispense_on: str, dispense_off: str, on_delay_ms: float, off_delay_ms: float,
                         dialect: str) -> DelayedProgram:
    """``text`` with a dwell of ``on_delay_ms`` (ms) after each ``dispense_on`` line and of
    ``off_delay_ms`` after each ``dispense_off`` line, written in ``dialect``'s G4 unit; a zero
    delay adds nothing.  KeyError for an unknown dialect."""
    rules = DIALECTS[dialect]
    on_key, off_key = _key(dispense_on), _key(dispense_off)
    on_dwell = rules.dwell(on_delay_ms / 1000.0) if on_delay_ms > 0 else None
    off_dwell = rules.dwell(off_delay_ms / 1000.0) if off_delay_ms > 0 else None
    out: list[str] = []
    ons = offs = 0
    for raw in text.splitlines():
        out.append(raw)
        if on_dwell is None and off_dwell is None:
            continue
        key = _key(raw) if raw.strip() else ""
        if not key:
            continue
        if on_dwell is not None and key == on_key:
            out.append(on_dwell)
            ons += 1
        elif off_dwell is not None and key == off_key:
            out.append(off_dwell)
            offs += 1
    return DelayedProgram("\n".join(out) + ("\n" if text.endswith("\n") else ""), ons, offs)
