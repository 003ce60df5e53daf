"""The one G-code reader: a modal interpreter that turns program text into moves.

Every consumer of G-code in the service reads programs through :func:`read_program` — the
time estimator, the 3-D view and the metadata stored with programs and artifacts — so they
agree on what a program does.  Lines are tokenized by :func:`app.gcode.lines.read_lines`
(shared with the program warp).  (The hardware package keeps its own line codec: it frames
and checksums lines, it does not interpret them.)

Semantics (RS274/NGC as Marlin, grbl and LinuxCNC share them):

* comments ``;...`` and ``(...)``, line numbers ``N..`` and ``*checksum`` are dropped; words
  are case-insensitive; several G/M codes may share a line and act in order;
* motion is modal: a line with axis words and no motion code repeats the last of
  ``G0 G1 G2 G3`` (none before the first: such a line is ignored, as grbl reports error 31);
* ``G20``/``G21`` set inches/millimetres for axis words, arc centres and ``F``; A/C are degrees;
* ``G90``/``G91`` absolute/relative XYZ (and A/C); ``M82``/``M83`` absolute/relative E;
* ``G92`` declares the current position to be the given coordinates: the *machine* position
  does not move, the program frame shifts.  Positions reported here are machine positions
  (what the nozzle really does), so ``G92`` never produces a move;
* ``G28`` homes the named axes (all XYZ when none is named) to machine zero and clears their
  ``G92`` shift (Marlin's behaviour); it is reported as a move flagged ``home``;
* ``G2``/``G3`` arcs in the XY plane (``G17``; ``G18``/``G19`` are refused) with ``I J``
  centre offsets or ``R`` radius, helical in Z and linear in E, are split into chords whose
  sagitta is at most ``arc_tolerance_mm`` (:func:`app.gcode.arcs.arc_chord_counts`).  Each
  arc's chords are counted before any is made, against a budget derived from the program's
  size (:func:`arc_chord_budget`): an arc of radius 1e9 mm is refused naming its line
  (:class:`ArcBudgetError`) in microseconds, never expanded;
* ``G4 P<ms>`` / ``G4 S<s>`` dwell: the machine stops there;
* axis words on a line with an M code and no G code are that code's arguments (``M92 X80``),
  except beside the dispenser's and E mode's codes; G10, G53, G38.x... own their axis words too;
  the settings :data:`SETTING_CODES` do not;
* the dispenser is on between the profile's exact ``dispense_on`` and ``dispense_off`` lines
  when given, else between the command words ``M3 M4 M7 M8 M106`` and ``M5 M9 M107`` (an on
  word with ``S0``, e.g. Marlin's ``M106 S0``, is off);
* ``;LAYER:n`` (or ``;LAYER n``) comments tag the following moves with layer ``n``;
* ``M201 M203 M204 M205`` (machine limits) are collected in order for the estimator.
"""

from __future__ import annotations

import math
import re
from array import array
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from app.gcode.arcs import FULL_CIRCLE_SWEEP_RAD, MIN_ARC_TOLERANCE_MM, arc_chord_counts
from app.gcode.lines import GcodeLine, GcodeReadError, iter_lines, read_lines
from app.geometry.tolerance import DEGENERATE_LENGTH_MM, LENGTH_EPS_MM

#: an arc budget: this many chords, plus ``ARC_CHORDS_PER_BYTE`` per byte of program, at most
#: ``MAX_ARC_CHORDS`` (:func:`arc_chord_budget`)
BASE_ARC_CHORDS = 10_000
ARC_CHORDS_PER_BYTE = 8  # a 20-byte full-circle line may hold r ~ 8 mm at 0.002 mm: real drill and outline circles pass
MAX_ARC_CHORDS = 1_000_000

INCH_MM = 25.4
DEFAULT_ON = frozenset({"M106", "M8", "M3", "M4", "M7"})
DEFAULT_OFF = frozenset({"M107", "M9", "M5"})
LIMIT_CODES = frozenset({"M201", "M203", "M204", "M205"})
#: G codes that set something without changing where a move goes (plane XY, feed per minute,
#: compensation and canned-cycle cancels, the first work offset, path control)
SETTING_CODES = frozenset({"G17", "G40", "G49", "G54", "G61", "G64", "G80", "G94"})
#: M codes that may share a line with a modal move (dispenser, E mode)
_MOVING_M = DEFAULT_ON | DEFAULT_OFF | {"M82", "M83"}
RAPID, FEED, ARC_CW, ARC_CCW, HOME = 0, 1, 2, 3, 28

#: a ``;LAYER:n`` tag: the moves after it belong to layer n
LAYER_TAG = re.compile(r";\s*LAYER[:\s]*(-?\d+)", re.IGNORECASE)
_LAYER = LAYER_TAG
_PAREN = re.compile(r"\([^)]*\)")
_LINE_NUMBER = re.compile(r"^N\d+\s*")
_AXES = "XYZE"


@dataclass(frozen=True)
class ReadOptions:
    """How to read a program.

    ``dispense_on``/``dispense_off``: the machine profile's exact lines (whitespace and case
    are normalised), replacing the default command words; ``arc_tolerance_mm``: the largest
    sagitta of an arc's chords (mm); ``feed_mm_s``: the feed until the first ``F`` (mm/s);
    ``keep_still``: a motion line that moves nothing (a repeated retract) is reported as a
    zero-length move instead of left out; ``max_arc_chords``: the most chords all arcs
    together may be split into, counted before any is expanded (:class:`ArcBudgetError`
    beyond it); None: :func:`arc_chord_budget` of the program's size (there is no unbounded
    reading).
    """

    dispense_on: str | None = None
    dispense_off: str | None = None
    arc_tolerance_mm: float = 0.002
    feed_mm_s: float = 25.0
    keep_still: bool = False
    max_arc_chords: int | None = None


class ArcBudgetError(GcodeReadError):
    """The program's arcs need more chords than their budget allows (field
    ``arc_tolerance_mm``; value: the line, the budget and the chords counted)."""


def beyond_size_budget(exc: ArcBudgetError, text_bytes: int) -> ArcBudgetError | None:
    """The refusal of a program of ``text_bytes`` bytes when the chords counted up to ``exc``
    (raised under a budget no larger than :func:`arc_chord_budget` of its size) are already
    beyond that budget (then ``exc``'s line is the first arc beyond it: the count before it
    was within the smaller budget); None when reading it again with that budget may succeed."""
    budget = arc_chord_budget(text_bytes)
    seen = exc.value if isinstance(exc.value, dict) else {}
    chords, line = int(seen.get("chords", 0)), seen.get("line")
    if chords <= budget:
        return None
    return ArcBudgetError(f"line {line}: the arcs need at least {chords} chords, more than the {budget} a program "
                          f"of {text_bytes} bytes may have", field=exc.field,
                          value={"line": line, "max_chords": budget, "chords": chords})


def arc_chord_budget(text_bytes: int) -> int:
    """The most arc chords a program of ``text_bytes`` bytes may be split into:
    ``BASE_ARC_CHORDS + ARC_CHORDS_PER_BYTE * text_bytes``, at most ``MAX_ARC_CHORDS``
    (a chord costs ~2 us and ~250 bytes while read: 1e6 chords ~2 s, ~250 MB)."""
    return min(MAX_ARC_CHORDS, BASE_ARC_CHORDS + ARC_CHORDS_PER_BYTE * max(0, int(text_bytes)))


@dataclass(frozen=True)
class Program:
    """Every move of a program, m of them, in machine coordinates (mm, degrees, s).

    start, end: (m, 4) float64 x, y, z, e before/after each move; rotary: (m, 2) float64 A, C
    (degrees) after each move; feed_mm_s: (m,) requested feed; motion: (m,) int8 — RAPID,
    FEED, ARC_CW, ARC_CCW (one entry per chord) or HOME; dispense: (m,) bool — a feed move
    while the dispenser is on or the extruder advances; layer: (m,) int64 (-1 before any tag);
    line: (m,) int64 1-based source line; stop_before: (m,) bool — the machine stops (dwell)
    between the previous move and this one.  ``dwell_s``: total dwell; ``limits``: the
    M201/M203/M204/M205 commands in order as (code, {letter: value}).
    """

    start: npt.NDArray[np.float64]
    end: npt.NDArray[np.float64]
    rotary: npt.NDArray[np.float64]
    feed_mm_s: npt.NDArray[np.float64]
    motion: npt.NDArray[np.int8]
    dispense: npt.NDArray[np.bool_]
    layer: npt.NDArray[np.int64]
    line: npt.NDArray[np.int64]
    stop_before: npt.NDArray[np.bool_]
    dwell_s: float
    limits: tuple[tuple[str, dict[str, float]], ...]

    @property
    def count(self) -> int:
        """The number of moves m."""
        return len(self.start)

    @property
    def home(self) -> npt.NDArray[np.bool_]:
        """(m,) bool: homing moves (they take no planned time)."""
        home: npt.NDArray[np.bool_] = self.motion == HOME
        return home

    def bounds(self) -> npt.NDArray[np.float64] | None:
        """(2, 3) lowest and highest XYZ the program commands (mm), None without moves.
        Homing moves do not count (home is the machine's own place, inside its volume by
        definition), nor does the position before the first move (never commanded)."""
        ends = self.end[~self.home, :3]
        if len(ends) == 0:
            return None
        return np.stack([ends.min(axis=0), ends.max(axis=0)])


@dataclass
class _State:
    """The modal state while reading (machine frame unless named otherwise)."""

    pos: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(4))
    shift: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(4))  # machine - program (G92)
    rot: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    scale: float = 1.0
    relative: bool = False
    relative_e: bool = False
    motion: int | None = None
    feed: float = 25.0
    dispensing: bool = False
    layer: int = -1
    stop_pending: bool = False


def _words_key(words: tuple[tuple[str, float], ...]) -> str:
    """A line's command as comparable text: ``m64  p0.0`` and ``M64 P0`` are the same."""
    return " ".join(f"{letter}{value:g}" for letter, value in words if letter != "N")


def _normalise(line: str | None) -> str | None:
    if line is None:
        return None
    parsed = read_lines(line, strict=False)
    return _words_key(parsed[0].words) if parsed else ""


def _strip(raw: str) -> str:
    """A line without comments, line number and checksum, upper case, blanks collapsed."""
    line = _PAREN.sub("", raw.split(";", 1)[0]).strip().upper()
    if "*" in line:
        line = line.split("*", 1)[0].strip()
    if line.startswith("N"):
        line = _LINE_NUMBER.sub("", line)
    return " ".join(line.split())


class MoveRow(NamedTuple):
    """One move as the reader emits it (the fields of :class:`Program`, one entry each)."""

    start: npt.NDArray[np.float64]
    end: npt.NDArray[np.float64]
    rotary: npt.NDArray[np.float64]
    feed_mm_s: float
    motion: int
    dispense: bool
    layer: int
    line: int
    stop_before: bool


_FLOATS_PER_ROW = 11  # start (4), end (4), rotary (2), feed
_INTS_PER_ROW = 5  # motion, dispense, layer, line, stop_before


class ModalReader:
    """The modal interpreter: fed line by line (:meth:`line`), it collects moves (one per move
    or arc chord, stored compactly; :meth:`moves_from` gives them as :class:`MoveRow`), dwells
    and limits; :meth:`program` gathers them.  ``size_bytes``: the program's size, from
    which the arcs' chord budget is derived unless ``options.max_arc_chords`` gives one
    (:func:`arc_chord_budget`; 0: the base budget)."""

    def __init__(self, options: ReadOptions, size_bytes: int = 0) -> None:
        self.options = options
        self.max_arc_chords = (options.max_arc_chords if options.max_arc_chords is not None
                               else arc_chord_budget(size_bytes))
        self.on_line = _normalise(options.dispense_on)
        self.off_line = _normalise(options.dispense_off)
        self.state = _State(feed=options.feed_mm_s)
        # each move as plain numbers (a million moves: ~130 MB, not ~1 GB of small arrays)
        self.floats = array("d")
        self.ints = array("q")
        self.dwell = 0.0
        self.limits: list[tuple[str, dict[str, float]]] = []
        self.text = ""  # the current line, stripped
        self.chords = 0  # arc chords emitted so far

    def emit(self, start: npt.NDArray[np.float64], end: npt.NDArray[np.float64], motion: int, number: int,
             extrudes: bool) -> None:
        """Record a move from ``start`` to ``end`` (4,) mm under the current modal state."""
        s = self.state
        dispense = motion in (FEED, ARC_CW, ARC_CCW) and (s.dispensing or extrudes)
        self.floats.extend(start.tolist())
        self.floats.extend(end.tolist())
        self.floats.extend(s.rot.tolist())
        self.floats.append(s.feed)
        self.ints.extend((motion, dispense, s.layer, number, s.stop_pending))
        s.stop_pending = False

    def line(self, parsed: GcodeLine) -> None:
        """Interpret one tokenized line."""
        s, number = self.state, parsed.number
        tag = _LAYER.search(parsed.text)
        if tag:
            s.layer = int(tag.group(1))
        if not parsed.words:
            return
        self.text = _strip(parsed.text)
        key = _words_key(parsed.words)
        if self.on_line is not None and key == self.on_line:
            s.dispensing = True
            return
        if self.off_line is not None and key == self.off_line:
            s.dispensing = False
            return
        codes = [f"{letter}{value:g}" for letter, value in parsed.words if letter in "GM"]
        values = {letter: value for letter, value in parsed.values.items() if letter not in "GMN"}
        motion_here: int | None = None
        # a non-motion code on this line owns the axis words (an M code's arguments: M92 X80)
        axis_consumer = not parsed.g and any(f"M{m:g}" not in _MOVING_M for m in parsed.m)
        for code in codes:
            axis_consumer |= self.modal(code, values, number)
            if code in ("G0", "G1", "G2", "G3"):
                motion_here = int(code[1:])
        if "F" in values:
            s.feed = values["F"] * s.scale / 60.0
        if axis_consumer:
            return
        if motion_here is not None:
            s.motion = motion_here
        if s.motion is None or not any(k in values for k in "XYZEAC"):
            return
        self.move(values, number)

    def modal(self, code: str, values: dict[str, float], number: int) -> bool:
        """Apply one non-motion code; True when it consumes the line's axis words."""
        s = self.state
        if self.on_line is None and code in DEFAULT_ON:
            s.dispensing = values.get("S") != 0.0  # M106 S0, M3 S0: the output at duty 0 is off
        elif self.off_line is None and code in DEFAULT_OFF:
            s.dispensing = False
        elif code == "G20":
            s.scale = INCH_MM
        elif code == "G21":
            s.scale = 1.0
        elif code == "G90":
            s.relative = False
        elif code == "G91":
            s.relative = True
        elif code == "M82":
            s.relative_e = False
        elif code == "M83":
            s.relative_e = True
        elif code in ("G18", "G19"):
            raise GcodeReadError(f"line {number}: only the XY plane (G17) is supported for arcs",
                                 field="gcode", value=number)
        elif code == "G4":
            self.dwell += values.get("P", 0.0) / 1000.0 + values.get("S", 0.0)
            s.stop_pending = True
            return True
        elif code == "G92":
            for i, axis in enumerate(_AXES):
                if axis in values:
                    unit = 1.0 if axis == "E" else s.scale
                    s.shift[i] = s.pos[i] - values[axis] * unit
            return True
        elif code == "G28":  # "G28 X" and "G28 X0" both home X
            letters = set(re.sub(r"G\s*28(?![\d.])", "", self.text))
            named = [axis for axis in "XYZ" if axis in letters] or list("XYZ")
            target = s.pos.copy()
            for axis in named:
                target[_AXES.index(axis)] = 0.0
                s.shift[_AXES.index(axis)] = 0.0
            self.emit(s.pos, target, HOME, number, False)
            s.pos = target
            s.stop_pending = True
            return True
        elif code in LIMIT_CODES:
            self.limits.append((code, dict(values)))
            return True
        elif code.startswith("G") and code not in ("G0", "G1", "G2", "G3") and code not in SETTING_CODES:
            return True  # G10, G53, G38.x...: axis words are not a move of ours
        return False

    def target(self, values: dict[str, float]) -> npt.NDArray[np.float64]:
        """The machine position (4,) mm that the axis words ``values`` command (updates A/C)."""
        s = self.state
        target = s.pos.copy()
        for i, axis in enumerate(_AXES):
            if axis not in values:
                continue
            if axis == "E":
                relative, unit = s.relative_e or s.relative, 1.0
            else:
                relative, unit = s.relative, s.scale
            target[i] = s.pos[i] + values[axis] * unit if relative else values[axis] * unit + s.shift[i]
        for k, axis in enumerate("AC"):
            if axis in values:
                s.rot[k] = s.rot[k] + values[axis] if s.relative else values[axis]
        return target

    def move(self, values: dict[str, float], number: int) -> None:
        """Emit the move (or arc chords) that the axis words ``values`` command."""
        s = self.state
        start = s.pos.copy()
        rotated = "A" in values or "C" in values
        end = self.target(values)
        extrudes = bool(end[3] > start[3] + DEGENERATE_LENGTH_MM)
        if s.motion in (ARC_CW, ARC_CCW):
            points = self.arc_points(start, end, values, number)
            for a, b in zip(points[:-1], points[1:]):
                self.emit(a, b, s.motion, number, extrudes)
        elif np.any(end != start) or rotated or self.options.keep_still:
            self.emit(start, end, s.motion if s.motion is not None else FEED, number, extrudes)
        s.pos = end

    def arc_points(self, start: npt.NDArray[np.float64], end: npt.NDArray[np.float64], values: dict[str, float],
                   number: int) -> npt.NDArray[np.float64]:
        """(k + 1, 4) chord points of an XY arc from ``start`` to ``end`` (helical Z, linear E)."""
        s = self.state
        clockwise = s.motion == ARC_CW
        if "R" in values:
            radius = values["R"] * s.scale
            chord = end[:2] - start[:2]
            half = float(np.hypot(*chord)) / 2.0
            if half < DEGENERATE_LENGTH_MM or abs(radius) < half - LENGTH_EPS_MM:
                raise GcodeReadError(f"line {number}: arc radius {values['R']:g} cannot join its end points",
                                     field="gcode", value=number)
            offset = math.sqrt(max(radius * radius - half * half, 0.0))
            middle = (start[:2] + end[:2]) / 2.0
            normal = np.array([-chord[1], chord[0]]) / (2.0 * half)
            # the centre lies left of the chord for a short CCW (or long CW) arc
            sign = 1.0 if (clockwise == (radius < 0)) else -1.0
            centre = middle + sign * offset * normal
        elif "I" in values or "J" in values:
            centre = start[:2] + np.array([values.get("I", 0.0), values.get("J", 0.0)]) * s.scale
        else:
            raise GcodeReadError(f"line {number}: an arc needs I/J or R", field="gcode", value=number)
        r0 = float(np.hypot(*(start[:2] - centre)))
        r1 = float(np.hypot(*(end[:2] - centre)))
        if r0 < LENGTH_EPS_MM or abs(r0 - r1) > max(0.005, 1e-3 * r0):
            raise GcodeReadError(f"line {number}: arc end is not on its circle (radius {r0:.4f} vs {r1:.4f} mm)",
                                 field="gcode", value=number)
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
        sweep = a1 - a0
        if clockwise:
            sweep = sweep - 2 * math.pi if sweep >= -FULL_CIRCLE_SWEEP_RAD else sweep
        else:
            sweep = sweep + 2 * math.pi if sweep <= FULL_CIRCLE_SWEEP_RAD else sweep
        tol = max(self.options.arc_tolerance_mm, MIN_ARC_TOLERANCE_MM)
        count = int(arc_chord_counts(np.array([r0]), np.array([sweep]), tol)[0])
        budget = self.max_arc_chords
        if self.chords + count > budget:
            raise ArcBudgetError(f"line {number}: the arcs need more than {budget} chords at a chord "
                                 f"tolerance of {tol:g} mm (this arc of radius {r0:g} mm alone: {count})",
                                 field="arc_tolerance_mm",
                                 value={"line": number, "max_chords": budget, "chords": self.chords + count})
        self.chords += count
        t = np.linspace(0.0, 1.0, count + 1)
        angle = a0 + sweep * t
        radius_t = r0 + (r1 - r0) * t
        points = np.empty((count + 1, 4))
        points[:, 0] = centre[0] + radius_t * np.cos(angle)
        points[:, 1] = centre[1] + radius_t * np.sin(angle)
        points[:, 2] = start[2] + (end[2] - start[2]) * t
        points[:, 3] = start[3] + (end[3] - start[3]) * t
        points[0], points[-1] = start, end
        return points

    @property
    def move_count(self) -> int:
        """How many moves (and arc chords) have been read so far."""
        return len(self.ints) // _INTS_PER_ROW

    def moves_from(self, first: int) -> list[MoveRow]:
        """The moves read since the first ``first`` ones, as :class:`MoveRow`."""
        f, i = _FLOATS_PER_ROW, _INTS_PER_ROW
        out = []
        for k in range(first, self.move_count):
            v, n = self.floats[k * f:(k + 1) * f], self.ints[k * i:(k + 1) * i]
            out.append(MoveRow(np.array(v[0:4]), np.array(v[4:8]), np.array(v[8:10]), v[10], n[0], bool(n[1]), n[2],
                               n[3], bool(n[4])))
        return out

    def forget_moves_from(self, first: int) -> None:
        """Drop the moves read since the first ``first`` ones (a caller keeping its own records)."""
        del self.floats[first * _FLOATS_PER_ROW:]
        del self.ints[first * _INTS_PER_ROW:]

    def program(self) -> Program:
        """Everything read so far as a :class:`Program`."""
        floats = np.frombuffer(self.floats, dtype=np.float64).reshape(-1, _FLOATS_PER_ROW)
        ints = np.frombuffer(self.ints, dtype=np.int64).reshape(-1, _INTS_PER_ROW)
        return Program(floats[:, 0:4].copy(), floats[:, 4:8].copy(), floats[:, 8:10].copy(), floats[:, 10].copy(),
                       ints[:, 0].astype(np.int8), ints[:, 1].astype(bool), ints[:, 2].copy(), ints[:, 3].copy(),
                       ints[:, 4].astype(bool), self.dwell, tuple(self.limits))


def read_program(text: str | bytes, options: ReadOptions = ReadOptions()) -> Program:
    """Every move of G-code ``text`` (see the module docstring for the rules).

    Raises :class:`GcodeReadError` (field ``gcode``) when the bytes are not UTF-8 or an arc
    is malformed, :class:`ArcBudgetError` when the arcs need more chords than
    ``options.max_arc_chords`` (default: :func:`arc_chord_budget` of the text's size).
    """
    size = len(text)  # characters of a str: at most its bytes, so its budget is never larger
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise GcodeReadError("the program is not UTF-8 text", field="gcode", value=str(exc)[:80]) from None
    reader = ModalReader(options, size)
    for parsed in iter_lines(text, strict=False):
        reader.line(parsed)
    return reader.program()
