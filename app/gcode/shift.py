"""Shift a program's absolute Z by a constant (pure): the drift since calibration.

A machine whose Z drifted by e since its calibration puts every commanded Z e higher (or
lower) than it did then; a program written in the calibration's frame is made right by
adding ``dz`` (the probe's pad reading now minus at calibration) to every ABSOLUTE Z the
program commands.  Which Z words are absolute follows the modal state the one tokenizer
(:func:`app.gcode.lines.read_lines`) gives per line:

* ``G90``/``G91`` (absolute / relative distance): relative Z words are left alone;
* ``G20``/``G21``: the shift is written in the program's units (inches: dz / 25.4);
* ``G92 Z`` (declare the current position) is shifted too: the frame it declares must move
  with the moves around it;
* ``G28``/``G30`` values (intermediate points, ignored by Marlin) are left alone; ``G10``
  (coordinate-system offsets) is refused.

The result is then PROVED with the one modal reader (:func:`app.gcode.reader.read_program`):
every move of the shifted program must end exactly ``dz`` higher than the same move of the
original (homing moves and moves before the first absolute Z excepted) with X, Y and E
unchanged; a program for which that does not hold is refused (``ShiftError``), never
printed half-shifted.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from app.gcode.lines import GcodeReadError, read_lines
from app.gcode.reader import HOME, read_program
from app.gcode.writer import format_number

__all__ = ["ShiftError", "ShiftedProgram", "shift_z"]

INCH_MM = 25.4
_Z_WORD = re.compile(r"([Zz])\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")
_SKIP = (28.0, 30.0, 28.1, 30.1)         # their Z words are not targets
_REFUSE = (10.0,)


class ShiftError(GcodeReadError):
    """A program whose Z cannot be shifted safely (422, names the line)."""


@dataclass(frozen=True)
class ShiftedProgram:
    """text: the shifted program; dz_mm: the shift; shifted_lines: how many lines changed."""

    text: str
    dz_mm: float
    shifted_lines: int


def _decimals(text: str) -> int:
    return len(text.split(".", 1)[1]) if "." in text else 0


def _shift_line(raw: str, dz: float, number: int, min_decimals: int) -> str:
    body, sep, comment = raw.partition(";")
    found = list(_Z_WORD.finditer(body))
    if len(found) != 1:
        raise ShiftError(f"line {number}: {len(found)} Z words in {raw.strip()[:60]!r}", field="program",
                         value={"line": number, "text": raw.strip()[:80]})
    match = found[0]
    value = float(match.group(2)) + dz
    digits = max(_decimals(match.group(2)), min_decimals)
    new = body[:match.start()] + match.group(1) + format_number(value, digits, field="z") + body[match.end():]
    new = new.split("*", 1)[0].rstrip() if "*" in new else new   # a checksum would no longer hold
    return new + sep + comment


def shift_z(text: str, dz_mm: float, *, decimals: int = 4, tolerance_mm: float = 2e-4) -> ShiftedProgram:
    """``text`` with every absolute Z raised by ``dz_mm`` (mm; see the module docstring).

    decimals: at least this many decimals in a shifted Z word.  tolerance_mm: how far a
    move may differ from the exact shift in the proof (the rounding of the written words).
    Raises ShiftError for a program the shift cannot be proved on (G10, a Z word the modal
    state does not explain, two Z words on a line).
    """
    dz = float(dz_mm)
    if not np.isfinite(dz):
        raise ShiftError("the Z shift must be finite", field="dz_mm", value=str(dz_mm))
    lines = text.splitlines()
    if dz == 0.0:
        return ShiftedProgram(text, 0.0, 0)
    absolute, inches, changed = True, False, 0
    out = list(lines)
    for parsed in read_lines(text, strict=False):
        g = parsed.g
        if any(code in _REFUSE for code in g):
            raise ShiftError(f"line {parsed.number}: G10 (coordinate offsets) cannot be shifted", field="program",
                             value={"line": parsed.number, "text": parsed.text.strip()[:80]})
        for code in g:  # the modal words act before the line's motion
            absolute = True if code == 90.0 else False if code == 91.0 else absolute
            inches = True if code == 20.0 else False if code == 21.0 else inches
        if "Z" not in parsed.values or any(code in _SKIP for code in g):
            continue
        if not absolute and 92.0 not in g and 53.0 not in g:
            continue
        step = dz / INCH_MM if inches else dz
        out[parsed.number - 1] = _shift_line(parsed.text, step, parsed.number, decimals + (2 if inches else 0))
        changed += 1
    shifted = "\n".join(out) + ("\n" if text.endswith("\n") else "")
    _prove(text, shifted, dz, tolerance_mm)
    return ShiftedProgram(shifted, dz, changed)


def _prove(original: str, shifted: str, dz: float, tolerance_mm: float) -> None:
    """Every move of ``shifted`` ends where the same move of ``original`` does, Z raised by
    either 0 (before the program's first absolute Z, or after a homing) or dz (once raised,
    until the next homing), X, Y and E unchanged; ShiftError naming the first line that is not."""
    before, after = read_program(original), read_program(shifted)
    if before.count != after.count or not np.array_equal(before.line, after.line):
        raise ShiftError("the shifted program does not move like the original", field="program",
                         value={"moves": [before.count, after.count]})
    delta = after.end - before.end
    raised = np.abs(delta[:, 2] - dz) <= tolerance_mm
    level = np.abs(delta[:, 2]) <= tolerance_mm
    home = before.motion == HOME
    bad = (~raised & ~level) | (np.abs(delta[:, [0, 1, 3]]) > tolerance_mm).any(axis=1)
    since = 0  # once raised, a move may only be level again after a homing
    for i in range(before.count):
        since = 0 if home[i] else since
        if raised[i]:
            since = 1
        elif since and not home[i]:
            bad[i] = True
    if bad.any():
        i = int(np.argmax(bad))
        raise ShiftError(f"line {int(before.line[i])}: cannot shift this program's Z by {dz:+.4f} mm (the move "
                         f"would change by {delta[i, 2]:+.4f} mm)", field="program",
                         value={"line": int(before.line[i])})
