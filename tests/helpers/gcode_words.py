"""Test helper: five-axis G1 moves read back through the one G-code reader."""

from __future__ import annotations

import numpy as np

from app.gcode.reader import FEED, read_program


def g1_rows(text: str) -> np.ndarray:
    """(k, 6) X Y Z A C F (mm, degrees, mm/min) after every feed move in program order
    (the approach move included), as :func:`app.gcode.reader.read_program` reads them."""
    program = read_program(text)
    feed = program.motion == FEED
    return np.column_stack([program.end[feed, :3], program.rotary[feed], program.feed_mm_s[feed] * 60.0])


def g1_lines_missing(text: str, letters: str) -> list[str]:
    """The ``G1`` lines of ``text`` that lack one of ``letters`` (a literal check of what a
    post-processor wrote, e.g. every five-axis line names all of X Y Z A C)."""
    return [line for line in text.splitlines()
            if line.startswith("G1 ") and not all(f" {letter}" in f" {line}" for letter in letters)]
