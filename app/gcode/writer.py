"""Small shared G-code program builder (pure: builds text, touches no file).

Every Conforma program starts with the same header::

    ; conforma job=<id> kind=<kind> units=mm
    G21
    G90

(LinuxCNC adds ``G64 P0.001``, a 1 um blending bound) and then consists of moves
written with a fixed number of decimals (never ``-0.0000``).
Dialect knowledge (probe commands, "wait for moves", program end) lives in the one
table :data:`DIALECTS`; callers ask the builder, never spell dialect commands themselves.

Units: coordinates in mm, feeds in mm/min (the user-facing G-code boundary).
Re-building a program from the same inputs gives byte-identical text (no timestamps).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Final, Literal, get_args

import numpy as np
import numpy.typing as npt

from app.domain.errors import InvalidInput
from app.gcode.reader import LAYER_TAG, Program
from app.gcode.recorder import ProgramRecorder

#: the one list of G-code dialects a program is written for (a job kind that targets fewer
#: derives its subset from a capability of :data:`DIALECTS`, e.g. :data:`DISPENSING_DIALECTS`)
DialectName = Literal["marlin", "grbl", "linuxcnc"]
DIALECT_NAMES: Final[tuple[DialectName, ...]] = get_args(DialectName)
DEFAULT_DIALECT: Final[DialectName] = "marlin"  # programs for a printer (FDM, compensated traces, circuits, machines)
# probing and five-axis programs default to grbl (their API defaults since they were written)
DEFAULT_PROBING_DIALECT: Final[DialectName] = "grbl"
ProbeStyle = Literal["g38", "g30"]


class GcodeError(InvalidInput):
    """Bad input for a G-code program (a non-finite coordinate, an unknown dialect...)."""


@dataclass(frozen=True)
class Dialect:
    """What differs between firmware families.

    ``probe_styles`` lists the probing commands the firmware understands: ``"g38"`` is
    ``G38.2`` (probe toward a target along an axis, stop on trigger; grbl, LinuxCNC, and
    Marlin built with ``G38_PROBE_TARGET``), ``"g30"`` is Marlin's single-point ``G30``
    (probe straight down at X/Y; the firmware chooses the probing feed and lift).
    ``extrusion``: an E axis with heaters (FDM extrusion output; M104/M140/M82);
    ``machine_limits``: the program sets acceleration and junction deviation
    (``M204``/``M205``); ``motors_off``: the end section's motors-off command;
    ``dispense``: the default dispenser on/off commands (a machine profile overrides them);
    None: the dialect has none of its own (LinuxCNC's outputs are numbered, ``M64``/``M65 P<n>``,
    so its commands come from a machine profile or the request);
    ``dwell_ms``: ``G4 P`` counts milliseconds (Marlin) rather than seconds.
    """

    name: str
    probe_styles: tuple[str, ...]
    wait_for_moves: str
    program_end: str | None
    preamble: tuple[str, ...] = ()   # lines after the standard header
    extrusion: bool = False
    machine_limits: bool = False
    motors_off: str | None = None
    dispense: tuple[str, str] | None = ("M106 S255", "M107")
    dwell_ms: bool = False

    def dwell(self, seconds: float) -> str:
        """``G4`` dwell of ``seconds`` (s) in this dialect's unit: Marlin ``G4 P<ms>``
        (integer milliseconds), grbl/LinuxCNC ``G4 P<s>`` (3 decimals)."""
        if self.dwell_ms:
            return f"G4 P{round(seconds * 1000)}"
        return f"G4 P{seconds:.3f}"


#: the one table of the dialects' own dispenser commands (``Dialect.dispense``): every other
#: default (compensation, the job kinds, a new machine's profile, the mock firmware's dispenser
#: wiring) derives from it.  grbl: flood coolant ``M8``/``M9``, a plain digital pin (a valve or
#: a dispenser's trigger input) switched in step with motion; its spindle ``M3`` drives a PWM
#: output at the modal S word, which is 0 after reset, so a bare ``M3`` switches nothing.
#: Marlin: the part-cooling fan at full duty, ``M106 S255`` spelled out (Marlin's bare ``M106``
#: means S255 too, RepRapFirmware's bare ``M106`` only reports the fan).
DIALECTS: dict[str, Dialect] = {
    "grbl": Dialect("grbl", probe_styles=("g38",), wait_for_moves="G4 P0", program_end="M2",
                    dispense=("M8", "M9")),
    "marlin": Dialect("marlin", probe_styles=("g30", "g38"), wait_for_moves="M400",
                      program_end=None, extrusion=True, machine_limits=True, motors_off="M84",
                      dwell_ms=True),
    # LinuxCNC: a program file must end in M2/M30; G4 P0 ends blending (waits for moves);
    # its dispense outputs are M64/M65 P<n> (machine profile), not M106/M107 or M8/M9
    # G64 P0.001: LinuxCNC blends corners within 1 um (its default G64 has no bound)
    "linuxcnc": Dialect("linuxcnc", probe_styles=("g38",), wait_for_moves="G4 P0",
                        program_end="M2", preamble=("G64 P0.001",), dispense=None),
}
#: the dialects a print program can target without a machine profile: those whose dispenser
#: commands are the dialect's own (``Dialect.dispense``), in :data:`DialectName`'s order
DISPENSING_DIALECTS: Final[tuple[DialectName, ...]] = tuple(
    name for name in DIALECT_NAMES if DIALECTS[name].dispense is not None)

def own_dispense_text(index: int) -> str:
    """The dispensing dialects' own on (``index`` 0) or off (1) commands as text for a form or
    an API description, e.g. ``"marlin M106 S255, grbl M8"``."""
    return ", ".join(f"{name} {own_dispense(name)[index]}" for name in DISPENSING_DIALECTS)


def own_dispense(name: str) -> tuple[str, str]:
    """The dispenser (on, off) commands of dialect ``name`` itself; GcodeError (field
    ``dialect``) for an unknown dialect or one without its own (LinuxCNC)."""
    rules = DIALECTS.get(name)
    if rules is None or rules.dispense is None:
        raise GcodeError(f"the dialect {name!r} has no dispenser commands of its own; expected one of "
                         f"{', '.join(DISPENSING_DIALECTS)}", field="dialect", value=name)
    return rules.dispense


_AXIS_RE = re.compile(r"^[ABCEUVW]$")


def format_number(value: float, decimals: int, field: str = "value") -> str:
    """Fixed-decimal text of ``value``; negative zero prints as zero; NaN/inf -> GcodeError."""
    v = float(value)
    if not math.isfinite(v):
        raise GcodeError(f"{field} must be finite, got {value!r}", field=field, value=str(value))
    text = f"{v:.{decimals}f}"
    if text.startswith("-") and float(text) == 0.0:
        text = text[1:]
    return text


_AMBIGUOUS = 1e-6   # of the last decimal: closer than this to a half, numpy's scaled rounding may differ
_SCALED_MAX = 2.0 ** 40   # beyond this many units of the last decimal, round in Python


def as_written(values: npt.NDArray[np.float64], decimals: int) -> npt.NDArray[np.float64]:
    """``values`` (any shape) as ``f"{v:.{decimals}f}"`` reads back: ``round(v, decimals) + 0.0``
    (correctly rounded; -0.0 becomes 0.0), vectorised; the rare value whose scaled rounding is
    ambiguous is rounded by Python itself."""
    unit = 10.0 ** decimals
    scaled = values * unit
    out: npt.NDArray[np.float64] = np.rint(scaled) / unit
    frac = scaled - np.floor(scaled)
    doubt = (np.abs(frac - 0.5) < _AMBIGUOUS) | ~(np.abs(scaled) < _SCALED_MAX)
    if doubt.any():
        flat, src = out.reshape(-1), values.reshape(-1)
        for i in np.flatnonzero(doubt.reshape(-1)).tolist():
            flat[i] = round(float(src[i]), decimals)
    return out + 0.0


#: a raw line that moves nothing: a tool change, an M code with settings, a dwell
_STILL = re.compile(r"^\s*(T\d+|M\d+(\s+[SPQRT][-+]?[\d.]+)*|G4(\s+[PS][\d.]+)?)\s*$", re.IGNORECASE)


class ProgramBuilder:
    """Accumulates one G-code program.

    Parameters
    ----------
    dialect : "marlin" | "grbl" | "linuxcnc"
    kind : str
        Job kind written into the header (e.g. ``"probe_plan"``); no whitespace.
    job_id : str | None
        Job id for the header (``-`` when None).
    decimals : int
        Decimals for coordinates (mm); feeds use ``feed_decimals``.
    record : bool
        Follow every line as the reader reads it, for :meth:`program`.
    """

    def __init__(self, dialect: str, kind: str, job_id: str | None = None,
                 decimals: int = 4, feed_decimals: int = 1, record: bool = False) -> None:
        if dialect not in DIALECTS:
            raise GcodeError(f"unknown G-code dialect {dialect!r}; expected one of "
                             f"{sorted(DIALECTS)}", field="dialect", value=dialect)
        if not (0 <= int(decimals) <= 6) or not (0 <= int(feed_decimals) <= 6):
            raise GcodeError("decimals must be in 0..6", field="decimals", value=decimals)
        for name, text in (("kind", kind), ("job_id", job_id or "-")):
            if not text or any(c.isspace() for c in text) or ";" in text:
                raise GcodeError(f"{name} must be a non-empty word without spaces or ';'",
                                 field=name, value=text)
        self.dialect = DIALECTS[dialect]
        self.kind = kind
        self.job_id = job_id
        self.decimals = int(decimals)
        self.feed_decimals = int(feed_decimals)
        # record: every line is also handed to a ProgramRecorder (:meth:`program`)
        self._recorder = ProgramRecorder() if record else None
        self._lines: list[str] = []
        for line in (f"; conforma job={job_id or '-'} kind={kind} units=mm", "G21", "G90", *self.dialect.preamble):
            self._append(line)
        # the XYZ bounds of the written moves, as the reader reads them (from 0, 0, 0);
        # None once a line is written whose motion the builder does not follow (a probe, a
        # raw line other than a tool change, an M code or a dwell)
        self._pos: list[float] | None = [0.0, 0.0, 0.0]
        self._lo: list[float] | None = None
        self._hi: list[float] | None = None

    # -- formatting ---------------------------------------------------------------
    def _coord(self, axis: str, value: float) -> str:
        return axis + format_number(value, self.decimals, field=axis.lower())

    def _feed(self, feed_mm_min: float) -> str:
        if not math.isfinite(float(feed_mm_min)) or float(feed_mm_min) <= 0:
            raise GcodeError(f"feed must be a positive finite mm/min, got {feed_mm_min!r}",
                             field="feed_mm_min", value=str(feed_mm_min))
        return "F" + format_number(feed_mm_min, self.feed_decimals, field="feed_mm_min")

    def _words(self, x: float | None, y: float | None, z: float | None,
               extra_axes: dict[str, float]) -> list[str]:
        words = [self._coord(a, v) for a, v in (("X", x), ("Y", y), ("Z", z)) if v is not None]
        self._moved(words)
        for name, value in extra_axes.items():
            axis = name.upper()
            if not _AXIS_RE.match(axis):
                raise GcodeError(f"unknown extra axis {name!r}", field="axis", value=name)
            words.append(self._coord(axis, value))
        return words

    # -- program content ----------------------------------------------------------
    def comment(self, text: str) -> ProgramBuilder:
        """Append ``; text`` (one line; newlines and parentheses are replaced)."""
        self._append(self.comment_text(text))
        return self

    @staticmethod
    def comment_text(text: str) -> str:
        """The line :meth:`comment` writes for ``text``."""
        clean = " ".join(str(text).replace("(", "[").replace(")", "]").split())
        return f"; {clean}" if clean else ";"

    def rapid(self, x: float | None = None, y: float | None = None,
              z: float | None = None) -> ProgramBuilder:
        """Rapid move ``G0`` to the given coordinates (mm); at least one axis."""
        words = self._words(x, y, z, {})
        if not words:
            raise GcodeError("rapid move without any axis", field="axis", value=None)
        self._append_move("G0 " + " ".join(words), 0, words, None)
        return self

    def move(self, x: float | None = None, y: float | None = None, z: float | None = None,
             feed_mm_min: float | None = None, **extra_axes: float) -> ProgramBuilder:
        """Linear move ``G1`` (mm, feed in mm/min); extra axes such as ``a=``, ``c=``, ``e=``."""
        words = self._words(x, y, z, extra_axes)
        if not words:
            raise GcodeError("linear move without any axis", field="axis", value=None)
        feed = None
        if feed_mm_min is not None:
            feed = self._feed(feed_mm_min)
            words.append(feed)
        self._append_move("G1 " + " ".join(words), 1, words, feed)
        return self

    def probe(self, style: str, *, x: float | None = None, y: float | None = None,
              z: float | None = None, feed_mm_min: float | None = None) -> ProgramBuilder:
        """One probing command in this dialect.

        ``style="g38"``: ``G38.2 Z<z> F<feed>`` — move toward ``z`` (the deepest allowed
        point) and stop on trigger (an error/alarm if it never triggers).
        ``style="g30"``: Marlin ``G30 X<x> Y<y>`` — probe down at X/Y with the firmware's
        own probing feed (``feed_mm_min`` and ``z`` are not part of the command).
        """
        if style not in self.dialect.probe_styles:
            raise GcodeError(f"dialect {self.dialect.name} does not support probe style "
                             f"{style!r} (supports {list(self.dialect.probe_styles)})",
                             field="probe_style", value=style)
        if style == "g38":
            if z is None or feed_mm_min is None:
                raise GcodeError("G38.2 needs a target z and a feed", field="z", value=z)
            words = self._words(x, y, z, {}) + [self._feed(feed_mm_min)]
            self._append("G38.2 " + " ".join(words))
        else:
            if x is None or y is None:
                raise GcodeError("G30 needs x and y", field="x", value=x)
            self._append("G30 " + " ".join(self._words(x, y, None, {})))
        self._pos = None  # where a probing move stops is the part's business
        return self

    def wait_for_moves(self) -> ProgramBuilder:
        """Block until all queued moves finished (``M400`` Marlin, ``G4 P0`` grbl)."""
        self._append(self.dialect.wait_for_moves)
        return self

    def end(self) -> ProgramBuilder:
        """Program end marker where the dialect has one (grbl and LinuxCNC ``M2``)."""
        if self.dialect.program_end:
            self._append(self.dialect.program_end)
        return self

    def raw(self, line: str) -> ProgramBuilder:
        """Append one verbatim line (must not contain a newline)."""
        if "\n" in line or "\r" in line:
            raise GcodeError("raw line must not contain a newline", field="line",
                             value=line[:40])
        if not _STILL.match(line):
            self._pos = None
        self._append(line.rstrip())
        return self

    def coord_text(self, value: float, field: str) -> str:
        """:func:`format_number` of a coordinate (mm) at this builder's decimals."""
        text = f"{value:.{self.decimals}f}"
        if text[0] == "-" and float(text) == 0.0:
            text = text[1:]
        elif text[-1] in "fn":   # inf, nan
            format_number(value, self.decimals, field=field)
        return text

    def feed_word(self, feed_mm_min: float) -> str:
        """The ``F`` word of a feed (mm/min) as :meth:`move` writes it."""
        return self._feed(feed_mm_min)

    def extend_xy_moves(self, lines: list[str], xs: list[float], ys: list[float], es: list[float] | None,
                        feed_mm_min: float) -> None:
        """Append ``G1 X.. Y.. [E..]`` ``lines`` the caller formatted as :meth:`move` does
        (:meth:`coord_text`, :meth:`feed_word`; the feed on the first line only), with the
        values as written: ``xs``, ``ys``, ``es`` (None: no E words), ``feed_mm_min``."""
        self._lines.extend(lines)
        self._follow(np.column_stack([xs, ys, np.full(len(xs), np.nan)]))
        if self._recorder is not None:
            self._recorder.xy_block(lines, xs, ys, es, feed_mm_min)

    def extend_moves(self, points: npt.NDArray[np.float64], feed_mm_min: float | None = None) -> ProgramBuilder:
        """``G1 X.. Y.. Z..`` to each of ``points`` (k, 3) mm in order, the ``feed_mm_min`` on
        the first only: the lines and bounds ``k`` calls of :meth:`move` make, formatted at
        once (each number is :func:`as_written`'s value printed at the builder's decimals:
        the text ``move`` writes, negative zero as zero).  A non-finite coordinate is the
        GcodeError ``move`` raises, and nothing is written."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        if len(pts) == 0:
            return self
        bad = np.argwhere(~np.isfinite(pts))
        if len(bad):
            row, axis = (int(v) for v in bad[0])
            format_number(pts[row, axis], self.decimals, field="xyz"[axis])
        feed = None if feed_mm_min is None else self._feed(feed_mm_min)
        written = as_written(pts, self.decimals)
        line = f"G1 X{{:.{self.decimals}f}} Y{{:.{self.decimals}f}} Z{{:.{self.decimals}f}}"
        lines = [line.format(*row) for row in written.tolist()]
        if feed is not None:
            lines[0] += " " + feed
        rows = np.column_stack([written, np.full(len(written), np.nan), np.full(len(written), np.nan)])
        if feed is not None:
            rows[0, 4] = float(feed[1:])
        self.extend_block(lines, rows)
        return self

    def extend_block(self, lines: list[str], rows: npt.NDArray[np.float64]) -> None:
        """Append ``lines`` the caller formatted as :meth:`move` and :meth:`comment` write
        them: ``G1`` moves with X Y Z E words at this builder's decimals and an optional F
        word, or comments (a layer tag ``;LAYER:n`` as :meth:`raw` writes it: the builder
        follows no bounds after it); ``rows`` (len(lines), 5): per line the X, Y, Z, E and F
        (mm/min) values as written, NaN for a word the line has not (all NaN: a comment)."""
        self._lines.extend(lines)
        if self._pos is not None and any(LAYER_TAG.match(lines[i]) for i in
                                         np.flatnonzero(np.isnan(rows[:, :4]).all(axis=1)).tolist()):
            self._pos = None
        self._follow(rows[~np.isnan(rows[:, :4]).all(axis=1), :3])
        if self._recorder is not None:
            self._recorder.block(lines, rows)

    def _append(self, line: str) -> None:
        self._lines.append(line)
        if self._recorder is not None:
            self._recorder.line(line)

    def _append_move(self, line: str, motion: int, words: list[str], feed: str | None) -> None:
        """A G0/G1 ``line`` of the formatted ``words`` (``feed``: its F word, if any)."""
        self._lines.append(line)
        if self._recorder is not None:
            axes = [(w[0], float(w[1:])) for w in words if w[0] in "XYZE"]
            if len(axes) + (feed is not None) != len(words):   # another axis (A, C...): the reader's rules
                self._recorder.line(line)
            else:
                self._recorder.linear(line, motion, axes, None if feed is None else float(feed[1:]))

    def program(self) -> Program:
        """What :func:`app.gcode.reader.read_program` reads from :meth:`text` (default
        options), followed as the lines were written; needs ``record=True``."""
        if self._recorder is None:
            raise GcodeError("the builder was made without record=True", field="record", value=False)
        return self._recorder.program()

    def _moved(self, words: list[str]) -> None:
        """Follow a move to the (formatted) XYZ ``words``: the reader reads these numbers."""
        if self._pos is None:
            return
        for word in words:
            self._pos["XYZ".index(word[0])] = float(word[1:])
        self._lo = list(self._pos) if self._lo is None else [min(a, b) for a, b in zip(self._lo, self._pos)]
        self._hi = list(self._pos) if self._hi is None else [max(a, b) for a, b in zip(self._hi, self._pos)]

    def _follow(self, xyz: npt.NDArray[np.float64]) -> None:
        """Follow moves to the XYZ values as written ``xyz`` (m, 3), NaN where a move leaves an
        axis out (it keeps its value): :meth:`_moved` of each, at once."""
        if self._pos is None or len(xyz) == 0:
            return
        given = np.vstack([self._pos, xyz])
        since = np.where(np.isnan(given), 0, np.arange(len(given))[:, None])
        np.maximum.accumulate(since, axis=0, out=since)
        at = given[since, np.arange(3)][1:]   # the position after each move
        lo, hi = at.min(axis=0), at.max(axis=0)
        self._lo = lo.tolist() if self._lo is None else np.minimum(self._lo, lo).tolist()
        self._hi = hi.tolist() if self._hi is None else np.maximum(self._hi, hi).tolist()
        self._pos = at[-1].tolist()

    def bounds(self) -> list[list[float]] | None:
        """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` mm of the moves written, what
        :func:`app.gcode.reader.read_program` reads from the text (the position before the
        first move is 0, 0, 0; an axis a move leaves out keeps its value); None without
        moves or when a line was written whose motion the builder does not follow (a probing
        move, a raw line other than a tool change, an M code or a dwell)."""
        if self._pos is None or self._lo is None or self._hi is None:
            return None
        return [list(self._lo), list(self._hi)]

    @property
    def lines(self) -> tuple[str, ...]:
        """The program lines so far (no newlines)."""
        return tuple(self._lines)

    def text(self) -> str:
        """The program: lines joined with ``\\n``, ending in one newline."""
        return "\n".join(self._lines) + "\n"
