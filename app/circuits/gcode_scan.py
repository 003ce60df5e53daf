"""The program warp's first pass: a G-code program's moves, line by line, as arrays (pure).

:func:`scan_program` returns one record per source line (several for a G2/G3 arc, one per
chord; one per move of a line): its kind, its line, start and end ``[x, y, z, e]`` (machine
mm; NaN for lines that do not move), the motion code, the modal feed (mm/min, NaN before the
first ``F``) and whether the output writes E absolute (``M82``/``M83``).

The moves are what the one G-code reader (:class:`app.gcode.reader.ModalReader`) reads:
modal motion (axis words without a G word repeat the last of ``G0 G1 G2 G3``), several
codes on a line acting in order (``G91 G0 Z2``, ``G28 G91 Z0``), inches, relative moves,
``G92`` shifts, ``G28`` homing, arcs split into chords, line numbers, ``( )`` and ``;``
comments, ``%`` tape marks.  Plain programs (G0/G1 moves, modes, M/S/T codes, comments,
line numbers, tape marks) are read by a vectorised pass (one regular-expression check and
array arithmetic) that gives the reader's records bit for bit; everything else goes through
the reader line by line.  The test suite checks that both agree.

What the warp does not model is refused (:class:`WarpError` naming the line and its text),
never passed through: G codes other than motion, dwell, homing, the modes it rewrites
(G17 G20 G21 G90 G91 G92) and the harmless settings in :data:`PASSED_G`; rotary or extra
axes (A B C U V W); axis words before any motion mode; a dwell sharing a line with a move.

Record kinds: ``print`` (moves in x/y while dispensing or extruding, not G0), ``travel``
(moves in x/y otherwise), ``zonly``, ``eonly``, ``still`` (a motion line that changes
nothing, e.g. a repeated retract), ``home`` (G28), ``mode`` (a line of codes the warp
rewrites: units, distance mode, plane, G92) and ``other`` (written unchanged: M/S/T codes,
dwells, comments, settings).
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.circuits.errors import WarpError
from app.gcode.lines import GcodeLine, GcodeReadError, read_lines
from app.gcode.reader import DEFAULT_OFF, DEFAULT_ON, HOME, ArcBudgetError, ModalReader, ReadOptions, arc_chord_budget
from app.geometry.tolerance import DEGENERATE_LENGTH_MM

__all__ = ["Records", "scan_program", "scan_lines", "arc_chord_budget", "refuse_line", "MIN_ARC_CHORD_MM", "PRINT",
           "TRAVEL", "ZONLY", "EONLY", "STILL", "HOME_KIND", "MODE", "OTHER", "KIND_NAMES"]

PRINT, TRAVEL, ZONLY, EONLY, STILL, HOME_KIND, MODE, OTHER = range(8)
KIND_NAMES = ("print", "travel", "zonly", "eonly", "still", "home", "mode", "other")
DISPENSE_ON = frozenset(float(word[1:]) for word in DEFAULT_ON)    # the reader's dispenser words
DISPENSE_OFF = frozenset(float(word[1:]) for word in DEFAULT_OFF)
#: codes the warp rewrites: its output is absolute mm in the XY plane and machine coordinates
REWRITTEN_G = frozenset({17.0, 20.0, 21.0, 90.0, 91.0, 92.0})
#: settings written unchanged (feed per minute, cancels of cutter/length compensation and
#: canned cycles, the first work offset, path control): none changes where a move goes
PASSED_G = frozenset({40.0, 49.0, 54.0, 61.0, 64.0, 80.0, 94.0})
MOTION_G = frozenset({0.0, 1.0, 2.0, 3.0})
KNOWN_G = REWRITTEN_G | PASSED_G | MOTION_G | {4.0, 28.0}
AXIS_LETTERS = frozenset("XYZE")
UNMODELLED_AXES = frozenset("ABCUVW")
#: letters a rewritten line may carry besides its moves and modes (written on a line before them)
CARRIED_LETTERS = frozenset("MST")
#: letters whose meaning the warp takes over on a rewritten line
REWRITTEN_LETTERS = frozenset("GNXYZEIJRF")
#: the smallest arc chord sagitta (mm) the warp accepts
MIN_ARC_CHORD_MM = 1e-4

_PAREN = re.compile(r"\([^()\n]*\)")
_TAPE = re.compile(r"^[ \t]*%[ \t]*$", re.MULTILINE)
_COMMENT = re.compile(r";[^\n]*")
_LETTERS = bytes(range(65, 91)) + bytes(range(97, 123))
_LETTERS_TO_BLANK = bytes.maketrans(_LETTERS, b" " * len(_LETTERS))
_KEEP = np.zeros(256, bool)
_KEEP[list(_LETTERS) + [10]] = True
_PRINTABLE = bytes(range(0x20, 0x7F)) + b"\t\n"
_WORD_CHARS = _LETTERS + b"0123456789.+- \t\n"
_NUMBER_CHAR = np.zeros(256, bool)
_NUMBER_CHAR[list(b"0123456789.+-")] = True
_DIGIT_OR_DOT = np.zeros(256, bool)
_DIGIT_OR_DOT[list(b"0123456789.")] = True
_LETTER = np.zeros(256, bool)
_LETTER[list(_LETTERS)] = True
_BLANKS = b" \t"
_FAST_LETTERS = frozenset("GMXYZEFNST")
_FAST_G = frozenset({0.0, 1.0, 17.0, 20.0, 21.0, 90.0, 91.0}) | PASSED_G


@dataclass(frozen=True, eq=False)
class Records:
    """kind (n,) int8 (PRINT ...); line (n,) 0-based source line; start, end (n, 4) [x, y, z, e]
    mm (NaN for lines that do not move); motion (n,) int8 G code of a move (0-3, 28 for a
    homing move, -1 for lines that do not move); feed (n,) mm/min (NaN: none yet); e_abs (n,)
    bool; lines: the source lines (``text.splitlines()``); carried: {0-based line: words} the
    M/S/T words (and settings) of a line the warp rewrites, written before its moves."""

    kind: npt.NDArray[np.int8]
    line: npt.NDArray[np.int64]
    start: npt.NDArray[np.float64]
    end: npt.NDArray[np.float64]
    motion: npt.NDArray[np.int8]
    feed: npt.NDArray[np.float64]
    e_abs: npt.NDArray[np.bool_]
    lines: list[str]
    carried: dict[int, str]

    def refuse(self, i: int, message: str) -> WarpError:
        """A WarpError naming the source line of record ``i``."""
        return refuse_line(int(self.line[i]) + 1, self.lines[int(self.line[i])], message)


def refuse_line(number: int, text: str, message: str, field: str = "file") -> WarpError:
    """A WarpError naming source line ``number`` (1-based) and its text."""
    return WarpError(f"line {number}: {message}", field=field, value={"line": number, "text": text.strip()[:80]})


def scan_program(text: str, arc_chord_mm: float = 0.001) -> Records:
    """The records of ``text`` (see the module doc): vectorised when it can, else line by line."""
    fast = _scan_fast(text)
    return fast if fast is not None else scan_lines(text, arc_chord_mm)


def _fmt_word(letter: str, value: float) -> str:
    return f"{letter}{value:g}"


def _check_line(ln: GcodeLine, motion_set: bool) -> tuple[bool, str]:
    """Refuse what the warp does not model on one line; (the line is rewritten, its carried words)."""
    letters = {k for k, _ in ln.words}
    odd = letters & UNMODELLED_AXES
    if odd:
        raise refuse_line(ln.number, ln.text, f"the warp moves X, Y, Z and E only, not {''.join(sorted(odd))}")
    for code in ln.g:
        if code not in KNOWN_G:
            raise refuse_line(ln.number, ln.text, f"G{code:g} is not modelled by the warp")
    has_axes = bool(letters & AXIS_LETTERS)
    consumer = any(c in (4.0, 28.0, 92.0) for c in ln.g)
    if has_axes and not consumer and not motion_set and not any(c in MOTION_G for c in ln.g):
        raise refuse_line(ln.number, ln.text, "axis words before any motion mode (G0, G1, G2, G3)")
    rewritten = bool(set(ln.g) & (REWRITTEN_G | MOTION_G | {28.0})) or has_axes
    if not rewritten:
        return False, ""
    if 4.0 in ln.g:
        raise refuse_line(ln.number, ln.text, "a dwell (G4) must have a line of its own")
    extra = letters - REWRITTEN_LETTERS - CARRIED_LETTERS
    if extra:
        raise refuse_line(ln.number, ln.text, f"the warp rewrites this line and cannot carry its "
                          f"{''.join(sorted(extra))} words")
    carried = [_fmt_word(k, v) for k, v in ln.words if k in CARRIED_LETTERS or (k == "G" and v in PASSED_G)]
    return True, " ".join(carried)


def _row_kind(motion: int, start: npt.NDArray[np.float64], end: npt.NDArray[np.float64], dispense: bool) -> int:
    if motion == HOME:
        return HOME_KIND
    moved_xy = end[0] != start[0] or end[1] != start[1]
    if moved_xy:
        return PRINT if dispense else TRAVEL
    if end[2] != start[2]:
        return ZONLY
    return EONLY if end[3] != start[3] else STILL


def scan_lines(text: str, arc_chord_mm: float = 0.001, max_arc_chords: int | None = None) -> Records:
    """The line-by-line reader (every feature; WarpError names a refused line).  Arcs may need
    at most ``max_arc_chords`` chords (default :func:`arc_chord_budget` of the text's size),
    counted before any is expanded (WarpError, field ``arc_chord_mm``)."""
    budget = arc_chord_budget(len(text)) if max_arc_chords is None else max_arc_chords
    reader = ModalReader(ReadOptions(arc_tolerance_mm=arc_chord_mm, keep_still=True, max_arc_chords=budget))
    try:
        parsed = read_lines(text)
    except GcodeReadError as exc:
        raise WarpError(exc.message, field="file", value=exc.value) from None
    kinds: list[int] = []
    where: list[int] = []
    starts: list[npt.NDArray[np.float64]] = []
    ends: list[npt.NDArray[np.float64]] = []
    motions: list[int] = []
    feeds: list[float] = []
    eabs: list[bool] = []
    carried: dict[int, str] = {}
    nan4 = np.full(4, math.nan)
    scale, feed, e_abs = 1.0, math.nan, True
    for ln in parsed:
        rewritten, words = _check_line(ln, reader.state.motion is not None)
        for code in ln.g:
            if code in (20.0, 21.0):
                scale = 25.4 if code == 20.0 else 1.0
        if "F" in ln.values:
            feed = ln.values["F"] * scale
        for code in ln.m:
            if code in (82.0, 83.0):
                e_abs = code == 82.0
        before = reader.move_count
        try:
            reader.line(ln)
        except ArcBudgetError as exc:
            raise refuse_line(ln.number, ln.text, exc.message.split(": ", 1)[-1], field="arc_chord_mm") from None
        except GcodeReadError as exc:
            raise refuse_line(ln.number, ln.text, exc.message.split(": ", 1)[-1]) from None
        rows = reader.moves_from(before)
        if words:
            carried[ln.number - 1] = words
        if not rows:
            kinds.append(MODE if rewritten else OTHER)
            where.append(ln.number - 1)
            starts.append(nan4)
            ends.append(nan4)
            motions.append(-1)
            feeds.append(feed)
            eabs.append(e_abs)
            continue
        for row in rows:
            kinds.append(_row_kind(row.motion, row.start, row.end, row.dispense))
            where.append(ln.number - 1)
            starts.append(row.start)
            ends.append(row.end)
            motions.append(row.motion)
            feeds.append(feed)
            eabs.append(e_abs)
        reader.forget_moves_from(before)              # the warp keeps its own records
    n = len(kinds)
    return Records(np.array(kinds, dtype=np.int8), np.array(where, dtype=np.int64),
                   np.array(starts, float).reshape(n, 4), np.array(ends, float).reshape(n, 4),
                   np.array(motions, dtype=np.int8), np.array(feeds, float), np.array(eabs, bool),
                   [ln.text for ln in parsed], carried)


def _ffill(values: npt.NDArray[np.float64], is_set: npt.NDArray[np.bool_], initial: float) -> npt.NDArray[np.float64]:
    """values where is_set, else the last set value before (``initial`` before the first)."""
    idx = np.where(is_set, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], initial)


def _last_per_line(mask: npt.NDArray[np.bool_], tok_line: npt.NDArray[np.int64], value: npt.NDArray[np.float64],
                   n_lines: int) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """(has (n_lines,) bool, last value (n_lines,)) of the selected tokens (fancy assignment: last wins)."""
    has, last = np.zeros(n_lines, bool), np.zeros(n_lines)
    has[tok_line[mask]] = True
    last[tok_line[mask]] = value[mask]
    return has, last


def _first_per_line(letter_mask: npt.NDArray[np.bool_], tok_line: npt.NDArray[np.int64],
                    tok_val: npt.NDArray[np.float64],
                    n_lines: int) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """(has (n_lines,) bool, first value (n_lines,)) of one letter's words."""
    lines, vals = tok_line[letter_mask], tok_val[letter_mask]
    has, first = np.zeros(n_lines, bool), np.zeros(n_lines)
    u, i = np.unique(lines, return_index=True)
    has[u], first[u] = True, vals[i]
    return has, first


def _axis(reset: npt.NDArray[np.bool_], step: npt.NDArray[np.bool_],
          v: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """One axis's position after each motion line (m,): ``reset`` lines set it to v, ``step``
    lines add v; summed in program order exactly as the reader does."""
    if not step.any():
        return _ffill(v, reset, 0.0)
    if not reset.any():
        return np.cumsum(np.where(step, v, 0.0))
    out = _ffill(v, reset, 0.0)
    starts = np.flatnonzero(reset)
    bounds = np.concatenate([[0], starts, [len(v)]])
    for a, b in zip(bounds[:-1], bounds[1:]):
        if step[a:b].any():
            inc = np.where(step[a:b], v[a:b], 0.0)
            if reset[a]:
                inc[0] = v[a]
            out[a:b] = np.add.accumulate(inc)
    return out


def _blank(match: re.Match[str]) -> str:
    return " " * len(match.group(0))


def _word_values(body: bytes) -> npt.NDArray[np.float64] | None:
    """Every word's number in order, or None unless ``body`` (letters, digits, ``.+-``, blanks,
    line breaks) is words only: each letter followed on its line, after blanks, by exactly one
    well-formed number, and no number without its letter."""
    stream = np.frombuffer(body.translate(None, _BLANKS), np.uint8)
    is_letter, is_number = _LETTER[stream], _NUMBER_CHAR[stream]
    letters = int(np.count_nonzero(is_letter))
    if letters == 0:
        return np.zeros(0) if not is_number.any() else None
    # every letter directly followed by a number (blanks removed), and as many numbers as letters
    followed = np.zeros(len(stream), bool)
    followed[:-1] = is_number[1:]
    runs = int(np.count_nonzero(is_number[1:] & ~is_number[:-1])) + int(is_number[0])
    if not followed[is_letter].all() or runs != letters:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # a malformed number ("1.2.3", "1-") is refused
        try:
            value = np.fromstring(body.translate(_LETTERS_TO_BLANK), sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    return value if len(value) == letters else None   # "X1 2": two numbers, one letter


def _scan_fast(text: str) -> Records | None:
    """The vectorised reader, or None when the program needs the line-by-line one."""
    if "\r" in text:
        text = text.replace("\r\n", "\n")
        if "\r" in text:
            return None
    if not text.isascii() or text.encode("ascii").translate(None, _PRINTABLE):
        return None                                   # line breaks other than "\n", control bytes
    lines = text.splitlines()
    n_lines = len(lines)
    body_text = _COMMENT.sub("", text)
    if "(" in body_text:
        body_text = _PAREN.sub(_blank, body_text)
    if "%" in body_text:
        body_text = _TAPE.sub("", body_text)
    body = body_text.encode("ascii")
    if body.translate(None, _WORD_CHARS):
        return None                                   # not words only
    raw = np.frombuffer(body, np.uint8)
    is_e = (raw[1:] == 69) | (raw[1:] == 101)
    if (is_e & _DIGIT_OR_DOT[raw[:-1]]).any():
        return None                                   # "X1E5": an exponent or a word? the reader decides
    value = _word_values(body)
    if value is None:
        return None
    marks = np.frombuffer(body, np.uint8)
    marks = marks[_KEEP[marks]]                       # every word's letter, and the line breaks
    is_nl = marks == 10
    tok_line = (np.cumsum(is_nl) - is_nl)[~is_nl]
    code = marks[~is_nl].astype(np.int64)
    code = np.where(code >= 97, code - 32, code)
    if len(code) != len(value) or not np.isin(code, [ord(c) for c in _FAST_LETTERS]).all():
        return None
    g_tok, m_tok = code == ord("G"), code == ord("M")
    g_line, g_val = tok_line[g_tok], value[g_tok]
    if not np.isin(g_val, list(_FAST_G)).all():
        return None                                   # arcs, G92, G28, dwells...: the reader
    has: dict[str, npt.NDArray[np.bool_]] = {}
    first: dict[str, npt.NDArray[np.float64]] = {}
    for ch in "XYZEF":
        has[ch], first[ch] = _first_per_line(code == ord(ch), tok_line, value, n_lines)
    axes = has["X"] | has["Y"] | has["Z"] | has["E"]
    rewritten_g = np.zeros(n_lines, bool)
    rewritten_g[g_line[np.isin(g_val, [0.0, 1.0, 17.0, 20.0, 21.0, 90.0, 91.0])]] = True
    rewritten = rewritten_g | axes
    carried_tok = np.isin(code, [ord("M"), ord("S"), ord("T")]) | (g_tok & np.isin(value, list(PASSED_G)))
    carried: dict[int, list[str]] = {}
    for t in np.flatnonzero(carried_tok & rewritten[tok_line]).tolist():     # few: a post's preamble
        carried.setdefault(int(tok_line[t]), []).append(_fmt_word(chr(code[t]), float(value[t])))
    # the motion mode: the last G0/G1 on or before each line
    mo_has, mo_last = _last_per_line(g_tok & np.isin(value, (0.0, 1.0)), tok_line, value, n_lines)
    motion_mode = _ffill(mo_last, mo_has, -1.0)
    if (axes & (motion_mode < 0)).any():
        return None                                   # axis words before any motion mode: refused by the reader
    # M codes in order on a line, the last one winning
    disp_tok = m_tok & np.isin(value, list(DISPENSE_ON | DISPENSE_OFF))
    d_has, d_last = _last_per_line(disp_tok, tok_line, np.isin(value, list(DISPENSE_ON)).astype(float), n_lines)
    s_has, s_first = _first_per_line(code == ord("S"), tok_line, value, n_lines)
    d_last[s_has & (s_first == 0.0)] = 0.0            # an on word at duty 0 (M106 S0) is off, as the reader reads it
    dispensing = _ffill(d_last, d_has, 0.0) > 0.5
    e_tok = m_tok & np.isin(value, (82.0, 83.0))
    e_has, e_last = _last_per_line(e_tok, tok_line, (value == 82.0).astype(float), n_lines)
    e_abs = _ffill(e_last, e_has, 1.0) > 0.5
    u_has, u_last = _last_per_line(g_tok & np.isin(value, (20.0, 21.0)), tok_line,
                                   np.where(value == 20.0, 25.4, 1.0), n_lines)
    scale = _ffill(u_last, u_has, 1.0)
    a_has, a_last = _last_per_line(g_tok & np.isin(value, (90.0, 91.0)), tok_line, (value == 90.0).astype(float),
                                   n_lines)
    absolute = _ffill(a_last, a_has, 1.0) > 0.5
    mv = np.flatnonzero(axes)
    ends = np.empty((len(mv), 4))
    for i, ch in enumerate("XYZE"):
        given, v = has[ch][mv], first[ch][mv] * (scale[mv] if i < 3 else 1.0)   # E is never in inches
        rel = ~absolute[mv] if i < 3 else ~(e_abs[mv] & absolute[mv])
        ends[:, i] = _axis(given & ~rel, given & rel, v)
    starts = np.vstack([np.zeros((1, 4)), ends[:-1]])
    moved_xy = (ends[:, 0] != starts[:, 0]) | (ends[:, 1] != starts[:, 1])
    motion = motion_mode[mv]
    dispense = (motion != 0.0) & (dispensing[mv] | (ends[:, 3] > starts[:, 3] + DEGENERATE_LENGTH_MM))
    kind_mv = np.where(moved_xy, np.where(dispense, PRINT, TRAVEL),
                       np.where(ends[:, 2] != starts[:, 2], ZONLY, np.where(ends[:, 3] != starts[:, 3], EONLY, STILL)))
    kind = np.where(rewritten, MODE, OTHER).astype(np.int8)
    kind[mv] = kind_mv
    start, end = np.full((n_lines, 4), math.nan), np.full((n_lines, 4), math.nan)
    start[mv], end[mv] = starts, ends
    motion_out = np.full(n_lines, -1, np.int8)
    motion_out[mv] = motion
    feeds = _ffill(first["F"] * scale, has["F"], math.nan)
    return Records(kind, np.arange(n_lines, dtype=np.int64), start, end, motion_out, feeds, e_abs, lines,
                   {k: " ".join(v) for k, v in carried.items()})
