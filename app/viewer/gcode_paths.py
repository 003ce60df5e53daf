"""Moves of a G-code program as line segments for the view (dispense vs travel).

The program is read by the one G-code reader (:func:`app.gcode.reader.read_program`): a
move dispenses when it is a feed move (``G1``/``G2``/``G3``) while the dispenser is on or
the extruder advances; arcs are drawn as their chords; ``;LAYER:n`` comments tag moves
with layer ``n``; rotary ``A``/``C`` words (degrees) are carried per segment for
five-axis programs; positions are machine positions (``G92`` shifts the program frame,
``G28`` homes).  Moves that change neither XYZ nor A/C (extruder-only) are not drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.gcode.lines import GcodeReadError
from app.gcode.reader import ArcBudgetError, ReadOptions, read_program


class GcodeViewError(GcodeReadError):
    """A program cannot be read for the view (not text, or no moves)."""


@dataclass(frozen=True)
class ToolpathSegments:
    """Moves of a program, m segments.

    starts, ends: (m, 3) float64 mm (program coordinates); dispense: (m,) bool;
    layer: (m,) int64 (-1 before any ``;LAYER:`` tag); a_deg, c_deg: (m,) float64 rotary
    positions at the end of each move (0 when the program has none).
    """

    starts: np.ndarray
    ends: np.ndarray
    dispense: np.ndarray
    layer: np.ndarray
    a_deg: np.ndarray
    c_deg: np.ndarray

    @property
    def count(self) -> int:
        return len(self.starts)

    @property
    def has_rotary(self) -> bool:
        return bool(np.any(self.a_deg != 0.0) or np.any(self.c_deg != 0.0))


def parse_toolpath(text: str | bytes, dispense_on: str | None = None,
                   dispense_off: str | None = None, max_arc_chords: int | None = None) -> ToolpathSegments:
    """Segments of every move of ``text`` (see the module docstring for the rules).

    ``dispense_on``/``dispense_off``: the profile's exact lines (as a job result echoes
    them); when given they replace the default command words.  ``max_arc_chords``: the
    most chords its arcs may be drawn with (default: the budget of the text's size,
    :func:`app.gcode.reader.arc_chord_budget`), counted before any is made.
    Raises GcodeViewError when the text is not UTF-8 or has no move,
    :class:`ArcBudgetError` (naming the line) when its arcs need more chords.
    """
    try:
        program = read_program(text, ReadOptions(dispense_on=dispense_on, dispense_off=dispense_off,
                                                 max_arc_chords=max_arc_chords))
    except ArcBudgetError:
        raise
    except GcodeReadError as exc:
        raise GcodeViewError(exc.message, field="gcode", value=exc.value) from None
    previous_rot = np.vstack([np.zeros((1, 2)), program.rotary[:-1]]) if program.count else program.rotary
    drawn = (np.any(program.end[:, :3] != program.start[:, :3], axis=1)
             | np.any(program.rotary != previous_rot, axis=1))
    if not np.any(drawn):
        raise GcodeViewError("the program has no moves", field="gcode", value=len(text))
    return ToolpathSegments(program.start[drawn, :3].copy(), program.end[drawn, :3].copy(),
                            program.dispense[drawn].copy(), program.layer[drawn].copy(),
                            program.rotary[drawn, 0].copy(), program.rotary[drawn, 1].copy())
