"""The lowest and highest XYZ a program moves to, read block by block (pure, vectorised).

:class:`BoundsScan` is fed a program as blocks of whole lines (:meth:`BoundsScan.block`) and
keeps only the modal state and the running bounds: its memory is one block's arrays,
whatever the program's length.  It reads what :class:`app.gcode.reader.ModalReader` reads
(the module doc of :mod:`app.gcode.reader`), with one difference: an arc's extent is exact
(:func:`app.gcode.arcs.arc_extents`), never a set of chords, so an arc costs the same
whatever its radius.

Most lines are read by array arithmetic over the whole block: lines of words only (G0 G1 G2
G3 G4 G17 G20 G21 G90 G91 and the settings, M codes, X Y Z E I J R F S T N P...) with
comments, line numbers and checksums.  Any other line (G92, G28, rotary axes, text that is
not words, an exponent, a number beyond a double...) goes through the modal reader on its
own, between the runs of plain lines; a block with many such lines goes through it whole.
The test suite checks that both ways give the same bounds.
"""

from __future__ import annotations

import math
import re

import numpy as np
import numpy.typing as npt

from app.domain.errors import InvalidInput
from app.gcode.arcs import MIN_ARC_TOLERANCE_MM, ArcCircles, arc_chord_counts, arc_circles, arc_extents
from app.gcode.lines import GcodeLine, GcodeReadError, iter_lines
from app.gcode.reader import ARC_CCW, ARC_CW, HOME, SETTING_CODES, ModalReader, ReadOptions

__all__ = ["BoundsScan", "LineBounds"]

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

#: a line of words only: letters each followed by a number (no exponent, no second dot)
_PLAIN = re.compile(rb"^(?![ \t]*+(?:[A-Za-z][ \t]*+[-+]?+(?:\d++\.?+\d*+|\.\d++)(?![eE.\d])[ \t]*+)*+$)[^\n]*",
                    re.MULTILINE)
_COMMENT = re.compile(rb";[^\n]*")
_PAREN = re.compile(rb"\([^)\n]*\)")
_CHECKSUM = re.compile(rb"\*[^\n]*")
_LETTERS = bytes(range(65, 91)) + bytes(range(97, 123))
_LETTERS_TO_BLANK = bytes.maketrans(_LETTERS, b" " * len(_LETTERS))
_IS_LETTER = np.zeros(256, bool)
_IS_LETTER[list(_LETTERS)] = True
_UPPER = np.arange(256, dtype=np.uint8)
_UPPER[97:123] -= 32
_PLAIN_G = np.array(sorted({0.0, 1.0, 2.0, 3.0, 4.0, 17.0, 20.0, 21.0, 90.0, 91.0}
                           | {float(c[1:]) for c in SETTING_CODES}))
_MOVING_M = np.array([3.0, 4.0, 5.0, 7.0, 8.0, 9.0, 82.0, 83.0, 106.0, 107.0])
_LIMIT_M = np.array([201.0, 203.0, 204.0, 205.0])
#: a block goes through the modal reader whole when more than one line in this many needs it
_READER_SHARE = 8


def _ffill(values: Floats, is_set: Bools, initial: float) -> Floats:
    """values where is_set, else the last set value before (``initial`` before the first)."""
    idx = np.where(is_set, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], initial)


def _positions(entry: float, absolute: Floats, reset: Bools, step: Bools, increment: Floats) -> Floats:
    """One axis after each move (m,): ``reset`` moves go to ``absolute``, ``step`` moves add
    ``increment``, others stay; summed in program order from ``entry`` as the reader does."""
    if not step.any():
        return _ffill(absolute, reset, entry)
    inc = np.where(step, increment, 0.0)
    if not reset.any():
        return np.add.accumulate(np.concatenate([[entry], inc]))[1:]
    out = _ffill(absolute, reset, entry)
    cuts = np.concatenate([[0], np.flatnonzero(reset), [len(inc)]])
    for a, b in zip(cuts[:-1].tolist(), cuts[1:].tolist()):
        if b > a and step[a:b].any():
            seed = absolute[a] if reset[a] else (entry if a == 0 else out[a - 1])
            part = inc[a:b].copy()
            part[0] = seed if reset[a] else seed + part[0]
            out[a:b] = np.add.accumulate(part)
    return out


class _Words:
    """The words of a block's plain lines as per-line arrays (n lines): for each letter in
    ``first``, (has (n,), first value (n,)); the last motion, unit, distance and E-mode
    code of each line; G4 lines; lines that need the reader after all (``odd``)."""

    def __init__(self, body: bytes, n: int, odd: Bools) -> None:
        arr = np.frombuffer(body, np.uint8)
        is_letter = _IS_LETTER[arr]
        letters = _UPPER[arr[is_letter]]
        breaks = np.flatnonzero(arr == 10)
        line = np.searchsorted(breaks, np.flatnonzero(is_letter))
        value = np.zeros(0)
        if len(letters):                  # (numpy reads blanks alone as [-1.0])
            value = np.fromstring(body.translate(_LETTERS_TO_BLANK), sep=" ")
        if len(value) != len(letters):
            raise ValueError("the plain lines are not words only")
        is_g, is_m = letters == ord("G"), letters == ord("M")
        odd = odd.copy()
        odd[line[~np.isfinite(value)]] = True                  # the reader names the number
        odd[line[(letters == ord("A")) | (letters == ord("C"))]] = True
        odd[line[is_g & ~np.isin(value, _PLAIN_G)]] = True
        odd[line[is_m & np.isin(value, _LIMIT_M)]] = True
        has_g = np.zeros(n, bool)
        has_g[line[is_g]] = True
        axis_tok = np.isin(letters, np.frombuffer(b"XYZE", np.uint8))
        has_axes = np.zeros(n, bool)
        has_axes[line[axis_tok]] = True
        # an M code's own axis words (M92 X80) and a dwell beside a move: the reader
        owning = line[is_m & ~np.isin(value, _MOVING_M)]
        odd[owning[~has_g[owning] & has_axes[owning]]] = True
        motion_tok = is_g & np.isin(value, (0.0, 1.0, 2.0, 3.0))
        self.g4 = np.zeros(n, bool)
        self.g4[line[is_g & (value == 4.0)]] = True
        both = np.zeros(n, bool)
        both[line[motion_tok]] = True
        odd |= self.g4 & both
        keep = ~odd[line]
        self.odd = odd
        letters, line, value, is_g, is_m = letters[keep], line[keep], value[keep], is_g[keep], is_m[keep]
        self.first: dict[str, tuple[Bools, Floats]] = {}
        for ch in "XYZEIJR":
            sel = letters == ord(ch)
            lines, vals = line[sel], value[sel]
            head = np.ones(len(lines), bool)
            head[1:] = lines[1:] != lines[:-1]
            has, first = np.zeros(n, bool), np.zeros(n)
            has[lines[head]], first[lines[head]] = True, vals[head]
            self.first[ch] = (has, first)
        self.motion = self._last(is_g & np.isin(value, (0.0, 1.0, 2.0, 3.0)), line, value, n)
        self.scale = self._last(is_g & np.isin(value, (20.0, 21.0)), line, np.where(value == 20.0, 25.4, 1.0), n)
        self.relative = self._last(is_g & np.isin(value, (90.0, 91.0)), line, (value == 91.0) * 1.0, n)
        self.relative_e = self._last(is_m & np.isin(value, (82.0, 83.0)), line, (value == 83.0) * 1.0, n)

    @staticmethod
    def _last(mask: Bools, line: npt.NDArray[np.int64], value: Floats, n: int) -> tuple[Bools, Floats]:
        has, last = np.zeros(n, bool), np.zeros(n)
        has[line[mask]] = True
        last[line[mask]] = value[mask]        # fancy assignment: the last on a line wins
        return has, last


class LineBounds(ModalReader):
    """The modal reader fed line by line (:meth:`line`), keeping only the lowest and highest
    XYZ a non-homing move (or an arc, exactly) reaches; non-finite numbers refused naming the
    line.  :class:`BoundsScan` reads through it what its arrays do not."""

    def __init__(self, field: str, arc_chord_mm: float | None = None, max_arc_chords: int | None = None) -> None:
        super().__init__(ReadOptions())
        self.field = field
        self.low = np.full(3, np.inf)
        self.high = np.full(3, -np.inf)
        self.arc_chord_mm = arc_chord_mm
        self.chord_limit = max_arc_chords  # counting only: None counts without a limit
        self.chords = 0

    def line(self, parsed: GcodeLine) -> None:
        for letter, value in parsed.words:
            if not math.isfinite(value):
                raise InvalidInput(f"line {parsed.number}: {letter} is not a finite number", field=self.field,
                                   value={"line": parsed.number, "text": parsed.text.strip()[:80]})
        try:
            super().line(parsed)
        except GcodeReadError as exc:
            if exc.field != "gcode":
                raise
            raise GcodeReadError(exc.message, field=self.field, value=exc.value) from None

    def add(self, low: Floats, high: Floats) -> None:
        np.minimum(self.low, low, out=self.low)
        np.maximum(self.high, high, out=self.high)

    def emit(self, start: Floats, end: Floats, motion: int, number: int, extrudes: bool) -> None:
        if motion != HOME:
            self.add(end[:3], end[:3])
        self.state.stop_pending = False

    def move(self, values: dict[str, float], number: int) -> None:
        s = self.state
        if s.motion not in (ARC_CW, ARC_CCW):
            super().move(values, number)
            return
        start = s.pos.copy()
        end = self.target(values)
        ij = np.array([[values.get("I", 0.0), values.get("J", 0.0)]]) * s.scale
        r = values.get("R", 0.0)
        self.arcs(start[None], end[None], np.array([s.motion == ARC_CW]), ij, np.array([r * s.scale]),
                  np.array(["R" in values]), np.array(["I" in values or "J" in values]), np.array([r]),
                  np.array([number]))
        s.pos = end

    def arcs(self, start: Floats, end: Floats, clockwise: Bools, ij: Floats, r: Floats, use_r: Bools,
             use_ij: Bools, r_word: Floats, number: npt.NDArray[np.int64]) -> None:
        """Add k arcs' exact extents (see :func:`app.gcode.arcs.arc_circles` for the arrays)."""
        circles = arc_circles(start, end, clockwise, ij, r, use_r, use_ij, r_word)
        if circles.problem is not None:
            i, text = circles.problem
            raise GcodeReadError(f"line {int(number[i])}: {text}", field=self.field, value=int(number[i]))
        if self.arc_chord_mm is not None:
            self._count_chords(circles, number)
        low, high = arc_extents(start, end, circles)
        self.add(low.min(axis=0), high.max(axis=0))

    def _count_chords(self, circles: ArcCircles, number: npt.NDArray[np.int64]) -> None:
        """Add the chords the modal reader's rule splits these arcs into at ``arc_chord_mm``
        (counted, none made); GcodeReadError (field ``arc_chord_mm``) at the arc that takes
        the count beyond ``max_arc_chords``."""
        tol = max(float(self.arc_chord_mm or 0.0), MIN_ARC_TOLERANCE_MM)
        count = arc_chord_counts(circles.r0, circles.sweep, tol)
        total = self.chords + np.cumsum(count)
        budget = self.chord_limit
        if budget is not None and total[-1] > budget:
            i = int(np.argmax(total > budget))
            raise GcodeReadError(f"line {int(number[i])}: the arcs need more than {budget} chords at a chord "
                                 f"tolerance of {tol:g} mm", field="arc_chord_mm",
                                 value={"line": int(number[i]), "max_chords": budget})
        self.chords = int(total[-1])

    def bounds(self) -> list[list[float]] | None:
        if not np.isfinite(self.low).all():
            return None
        return [self.low.tolist(), self.high.tolist()]


class BoundsScan:
    """Fed blocks of whole lines in order (:meth:`block`), then :meth:`bounds`: the lowest and
    highest XYZ the program moves to (see :func:`app.jobs.gcode_meta.gcode_meta`).
    InvalidInput naming ``field`` and the line for a number that is not finite or an arc
    that is not one.  ``arc_chord_mm``: the arcs' chords at that sagitta are counted by the
    modal reader's rule (:attr:`chords`), none made; beyond ``max_arc_chords`` a
    GcodeReadError naming the field ``arc_chord_mm`` and the line."""

    def __init__(self, field: str = "file", arc_chord_mm: float | None = None,
                 max_arc_chords: int | None = None) -> None:
        self.reader = LineBounds(field, arc_chord_mm, max_arc_chords)

    @property
    def chords(self) -> int:
        """The chords the arcs read so far need at ``arc_chord_mm`` (0 without it)."""
        return self.reader.chords

    def bounds(self) -> list[list[float]] | None:
        """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` mm, None without moves."""
        return self.reader.bounds()

    def block(self, text: str, first: int) -> None:
        """Read ``text`` (whole lines; its first line is the program's line ``first``, 1-based)."""
        if not text:
            return
        plain = text.isascii() and "\r" not in text and not any(c in text for c in "\x0b\x0c\x1c\x1d\x1e")
        if plain:
            data = text.encode("ascii")
            n = data.count(b"\n") + (not data.endswith(b"\n"))
            body = _COMMENT.sub(b"", data) if b";" in data else data
            if b"(" in body:
                body = _PAREN.sub(b" ", body)
            if b"*" in body:
                body = _CHECKSUM.sub(b"", body)
            odd_spans = [(m.start(), m.end()) for m in _PLAIN.finditer(body) if m.end() > m.start()]
            if len(odd_spans) * _READER_SHARE <= n:
                self._plain_block(data, body, n, odd_spans, first)
                return
        for parsed in iter_lines(text, strict=False):
            self.reader.line(parsed._replace(number=parsed.number + first - 1))

    def _plain_block(self, data: bytes, body: bytes, n: int, odd_spans: list[tuple[int, int]], first: int) -> None:
        breaks = np.flatnonzero(np.frombuffer(body, np.uint8) == 10)
        odd = np.zeros(n, bool)
        if odd_spans:
            blanked = bytearray(body)
            for a, b in odd_spans:
                blanked[a:b] = b" " * (b - a)
            odd[np.searchsorted(breaks, [a for a, _ in odd_spans])] = True
            body = bytes(blanked)
        try:
            words = _Words(body, n, odd)
        except ValueError:                       # not words after all: the reader decides
            words = None
        readers = np.flatnonzero(words.odd) if words is not None else np.arange(n)
        if words is None or len(readers) * _READER_SHARE > n:
            for parsed in iter_lines(data.decode("ascii"), strict=False):
                self.reader.line(parsed._replace(number=parsed.number + first - 1))
            return
        data_breaks = np.flatnonzero(np.frombuffer(data, np.uint8) == 10)
        start = 0
        for k in readers.tolist() + [n]:
            if k > start:
                self._run(words, start, k, first)
            if k < n:
                a = int(data_breaks[k - 1]) + 1 if k > 0 else 0
                b = int(data_breaks[k]) if k < len(data_breaks) else len(data)
                for parsed in iter_lines(data[a:b].decode("ascii"), strict=False):
                    self.reader.line(parsed._replace(number=first + k))
            start = k + 1

    def _run(self, words: _Words, a: int, b: int, first: int) -> None:
        """Lines a..b-1 of the block (all plain) from the reader's state, which they update."""
        s = self.reader.state
        sl = slice(a, b)
        scale = _ffill(words.scale[1][sl], words.scale[0][sl], s.scale)
        relative = _ffill(words.relative[1][sl], words.relative[0][sl], float(s.relative)) > 0.5
        relative_e = _ffill(words.relative_e[1][sl], words.relative_e[0][sl], float(s.relative_e)) > 0.5
        motion = _ffill(words.motion[1][sl], words.motion[0][sl] & ~words.g4[sl],
                        -1.0 if s.motion is None else float(s.motion))
        has_axes = np.zeros(b - a, bool)
        for ch in "XYZE":
            has_axes |= words.first[ch][0][sl]
        moving = np.flatnonzero(has_axes & ~words.g4[sl] & (motion >= 0))
        s.scale = float(scale[-1])
        s.relative, s.relative_e = bool(relative[-1]), bool(relative_e[-1])
        if motion[-1] >= 0:
            s.motion = int(motion[-1])
        if len(moving) == 0:
            return
        ends = np.empty((len(moving), 4))
        for i, ch in enumerate("XYZE"):
            has, value = words.first[ch][0][sl][moving], words.first[ch][1][sl][moving]
            unit = scale[moving] if i < 3 else 1.0
            rel = relative[moving] if i < 3 else relative[moving] | relative_e[moving]
            ends[:, i] = _positions(float(s.pos[i]), value * unit + s.shift[i], has & ~rel, has & rel, value * unit)
        starts = np.concatenate([s.pos[None, :], ends[:-1]])
        code = motion[moving]
        arc = (code == ARC_CW) | (code == ARC_CCW)
        moved = (ends != starts).any(axis=1) & ~arc
        if moved.any():
            self.reader.add(ends[moved, :3].min(axis=0), ends[moved, :3].max(axis=0))
        if arc.any():
            pick = moving[arc] + a
            i_has, i_val = words.first["I"][0][pick], words.first["I"][1][pick]
            j_has, j_val = words.first["J"][0][pick], words.first["J"][1][pick]
            r_has, r_val = words.first["R"][0][pick], words.first["R"][1][pick]
            unit = scale[moving[arc]]
            self.reader.arcs(starts[arc], ends[arc], code[arc] == ARC_CW,
                             np.stack([np.where(i_has, i_val, 0.0), np.where(j_has, j_val, 0.0)], axis=1)
                             * unit[:, None], r_val * unit, r_has, i_has | j_has, r_val, pick + first)
        s.pos = ends[-1].copy()
