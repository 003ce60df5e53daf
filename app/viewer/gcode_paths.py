"""Moves of a G-code program as line segments for the view (dispense vs travel).

A move dispenses when it is a ``G1``/``G2``/``G3`` feed move while the dispenser is on
(between the profile's ``dispense_on`` and ``dispense_off`` lines; by default the
command words ``M106``/``M8``/``M3``/``M4`` switch it on and ``M107``/``M9``/``M5`` off)
or when it advances the extruder ``E``.  ``G0`` moves are travel.  Arcs are drawn as
their chord (the programs written here use none).  ``;LAYER:n`` comments tag the
following moves with layer ``n``.  Rotary ``A``/``C`` words (degrees) are carried per
segment for five-axis programs.  ``G20`` (inches) is converted to mm; ``G91`` relative
moves are accumulated.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from app.errors import InvalidInput

DEFAULT_ON = frozenset({"M106", "M8", "M3", "M4", "M7"})
DEFAULT_OFF = frozenset({"M107", "M9", "M5"})
_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_LAYER = re.compile(r";\s*LAYER\s*:\s*(-?\d+)", re.IGNORECASE)
INCH_MM = 25.4


class GcodeViewError(InvalidInput):
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


def _normalise(line: str | None) -> str | None:
    return None if line is None else " ".join(line.split(";")[0].upper().split())


def _strip(raw: str) -> str:
    """A line without ``(...)`` and ``;`` comments, line number and checksum, upper case."""
    line = re.sub(r"\([^)]*\)", "", raw.split(";", 1)[0]).strip().upper()
    if "*" in line:
        line = line.split("*", 1)[0].strip()
    if line.startswith("N"):
        line = re.sub(r"^N\d+\s*", "", line)
    return line


def parse_toolpath(text: str | bytes, dispense_on: str | None = None,
                   dispense_off: str | None = None) -> ToolpathSegments:
    """Segments of every move of ``text`` (see the module docstring for the rules).

    ``dispense_on``/``dispense_off``: the profile's exact lines (as a job result echoes
    them); when given they replace the default command words.
    Raises GcodeViewError when the text is not UTF-8 or has no move.
    """
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise GcodeViewError("the program is not UTF-8 text", field="gcode", value=str(exc)[:80]) from None
    on_line, off_line = _normalise(dispense_on), _normalise(dispense_off)
    pos = np.zeros(3)
    rot = {"A": 0.0, "C": 0.0}
    e_pos, scale, relative, relative_e, dispensing, layer = 0.0, 1.0, False, False, False, -1
    starts: list[list[float]] = []
    ends: list[list[float]] = []
    flags: list[bool] = []
    layers: list[int] = []
    rotary: list[tuple[float, float]] = []
    for raw in text.splitlines():
        tag = _LAYER.search(raw)
        if tag:
            layer = int(tag.group(1))
        line = _strip(raw)
        if not line:
            continue
        if on_line is not None and line == on_line:
            dispensing = True
            continue
        if off_line is not None and line == off_line:
            dispensing = False
            continue
        words = _WORD.findall(line)
        if not words:
            continue
        codes = [f"{letter}{int(float(value))}" for letter, value in words if letter in "GM" and float(value).is_integer()]
        values = {letter: float(value) for letter, value in words if letter not in "GMN"}
        for code in codes:
            if on_line is None and code in DEFAULT_ON:
                dispensing = True
            elif off_line is None and code in DEFAULT_OFF:
                dispensing = False
            elif code == "G20":
                scale = INCH_MM
            elif code == "G21":
                scale = 1.0
            elif code == "G90":
                relative = False
            elif code == "G91":
                relative = True
            elif code == "M82":
                relative_e = False
            elif code == "M83":
                relative_e = True
            elif code == "G92" and "E" in values:
                e_pos = values["E"]
        motion = next((c for c in codes if c in ("G0", "G1", "G2", "G3")), None)
        if motion is None:
            continue
        target = pos.copy()
        for k, axis in enumerate("XYZ"):
            if axis in values:
                target[k] = (pos[k] if relative else 0.0) + values[axis] * scale
        for axis in ("A", "C"):
            if axis in values:
                rot[axis] = (rot[axis] if relative else 0.0) + values[axis]
        extrudes = False
        if "E" in values:
            new_e = e_pos + values["E"] if relative_e else values["E"]
            extrudes = new_e > e_pos + 1e-12
            e_pos = new_e
        if np.any(target != pos) or "A" in values or "C" in values:
            starts.append(pos.tolist())
            ends.append(target.tolist())
            flags.append(motion != "G0" and (dispensing or extrudes))
            layers.append(layer)
            rotary.append((rot["A"], rot["C"]))
        pos = target
    if not starts:
        raise GcodeViewError("the program has no moves", field="gcode", value=len(text))
    rot_arr = np.asarray(rotary, dtype=float)
    return ToolpathSegments(np.asarray(starts, dtype=float), np.asarray(ends, dtype=float),
                            np.asarray(flags, dtype=bool), np.asarray(layers, dtype=np.int64),
                            rot_arr[:, 0].copy(), rot_arr[:, 1].copy())
