"""The program warp's first pass: a G-code program's modal interpretation as arrays (pure).

:func:`scan_program` returns one record per source line (several for a G2/G3 arc, one per
chord): its kind, its line, start and end ``[x, y, z, e]`` (absolute mm; NaN for lines that
do not move), the modal feed (mm/min, NaN when none was set) and whether E was absolute.

Two readers with the same result: a vectorised one (one regular-expression pass over the
whole text, the modal state carried by forward fills and cumulative sums) for programs of
G0/G1 moves, modes (G20/G21/G90/G91/G17-G19), M codes, ``;`` comments and plain words; and
the line-by-line reader (:func:`app.gcode.lines.read_lines`) for everything else (arcs, G92,
parenthesised comments, checksums, stray text), which also names refused lines.  The test
suite checks that both give identical records on programs using every supported feature.

Modal rules (both readers): a motion line is one with exactly one G code, 0-3, and an
X/Y/Z/E/I/J word; only motion lines set the feed; M codes of a line take effect before its
motion (M106/M8/M3/M4/M7 start dispensing, M107/M9/M5 stop it; M82/M83 absolute/relative E);
G20/G21 and G90/G91 on other lines.  A move is ``print`` when it moves in x/y, is not G0 and
extrudes or runs while dispensing; ``travel`` when it moves in x/y otherwise; ``zonly``,
``eonly``; ``other`` for a motion line that changes nothing and for non-motion lines except
``mode`` lines (only G17/G20/G21/G90/G91 codes).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.circuits.errors import WarpError
from app.gcode.lines import GcodeLine, read_lines
from app.geometry.tolerance import DEGENERATE_LENGTH_MM, LENGTH_EPS_MM

__all__ = ["Records", "scan_program", "scan_lines", "PRINT", "TRAVEL", "ZONLY", "EONLY", "MODE", "OTHER"]

PRINT, TRAVEL, ZONLY, EONLY, MODE, OTHER = range(6)
KIND_NAMES = ("print", "travel", "zonly", "eonly", "mode", "other")
DISPENSE_ON = frozenset({106.0, 8.0, 3.0, 4.0, 7.0})
DISPENSE_OFF = frozenset({107.0, 9.0, 5.0})
MODE_CODES = frozenset({17.0, 20.0, 21.0, 90.0, 91.0})

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_WORD = re.compile(rf"([A-Za-z])[ \t]*({_NUMBER})")
_COMMENT = re.compile(r";[^\n]*")
_EXPONENT = re.compile(rb"[0-9.][eE][-+]?[0-9]")
_LETTERS = bytes(range(65, 91)) + bytes(range(97, 123))
_LETTERS_TO_BLANK = bytes.maketrans(_LETTERS, b" " * len(_LETTERS))
_KEEP = np.zeros(256, bool)
_KEEP[list(_LETTERS) + [10]] = True
# words, blanks, line breaks and ; comments only (possessive: no backtracking)
_PLAIN = re.compile(rf"(?:[A-Za-z][ \t]*{_NUMBER}|[ \t\n]+|;[^\n]*)*+")
_UNUSUAL = re.compile(r"[^\t\n\r\x20-\x7e]")


@dataclass(frozen=True, eq=False)
class Records:
    """kind (n,) int (PRINT ...); line (n,) 0-based source line; start, end (n, 4) [x, y, z, e]
    mm (NaN for non-motion lines); feed (n,) mm/min (NaN: none yet); e_abs (n,) bool;
    lines: the source lines (``text.splitlines()``)."""

    kind: npt.NDArray[np.int8]
    line: npt.NDArray[np.int64]
    start: npt.NDArray[np.float64]
    end: npt.NDArray[np.float64]
    feed: npt.NDArray[np.float64]
    e_abs: npt.NDArray[np.bool_]
    lines: list[str]

    def refuse(self, i: int, message: str) -> WarpError:
        """A WarpError naming the source line of record ``i``."""
        return refuse_line(int(self.line[i]) + 1, self.lines[int(self.line[i])], message)


def refuse_line(number: int, text: str, message: str) -> WarpError:
    """A WarpError naming source line ``number`` (1-based) and its text."""
    return WarpError(f"line {number}: {message}", field="file", value={"line": number, "text": text.strip()[:80]})


def scan_program(text: str, arc_chord_mm: float = 0.001) -> Records:
    """The records of ``text`` (see the module doc): vectorised when it can, else line by line."""
    fast = _scan_fast(text)
    return fast if fast is not None else scan_lines(text, arc_chord_mm)


def _kind(g0: float, start: list[float], end: list[float], dispensing: bool) -> int:
    """The record kind (PRINT ...) of a motion from ``start`` to ``end`` [x, y, z, e]."""
    moved_xy = end[0] != start[0] or end[1] != start[1]
    de = end[3] - start[3]
    if moved_xy and g0 != 0.0 and (de > 0 or dispensing):
        return PRINT
    if moved_xy:
        return TRAVEL
    if end[2] != start[2]:
        return ZONLY
    return EONLY if de != 0 else OTHER


def _arc_points(ln: GcodeLine, start: list[float], end: list[float], values: dict[str, float], scale: float,
                clockwise: bool,
                arc_chord_mm: float) -> list[list[float]]:
    """End points [x, y, z, e] of the chords of a G2/G3 arc in the XY plane (I, J offsets from
    the start, or R: positive the shorter arc), each chord's sagitta <= ``arc_chord_mm``;
    z and e are shared out along the angle (helix)."""
    sx, sy, ex, ey = start[0], start[1], end[0], end[1]
    if "I" in values or "J" in values:
        cx, cy = sx + values.get("I", 0.0) * scale, sy + values.get("J", 0.0) * scale
    elif "R" in values:
        r = values["R"] * scale
        dx, dy = ex - sx, ey - sy
        chord = math.hypot(dx, dy)
        if chord == 0.0 or abs(r) < chord / 2 - LENGTH_EPS_MM:
            raise refuse_line(ln.number, ln.text, f"the arc's radius {abs(r):g} mm cannot join its ends "
                              f"{chord:g} mm apart")
        h = math.sqrt(max(r * r - chord * chord / 4, 0.0)) * (1 if (r > 0) != clockwise else -1)
        cx, cy = sx + dx / 2 - h * dy / chord, sy + dy / 2 + h * dx / chord
    else:
        raise refuse_line(ln.number, ln.text, "an arc needs I/J or R")
    radius = math.hypot(sx - cx, sy - cy)
    if radius <= 0.0:
        raise refuse_line(ln.number, ln.text, "the arc has zero radius")
    a0, a1 = math.atan2(sy - cy, sx - cx), math.atan2(ey - cy, ex - cx)
    ccw = (a1 - a0) % (2 * math.pi)
    if abs(ex - sx) + abs(ey - sy) <= DEGENERATE_LENGTH_MM:
        ccw = 2 * math.pi
    sweep = -(2 * math.pi - ccw if ccw < 2 * math.pi else 2 * math.pi) if clockwise else (ccw or 2 * math.pi)
    step = 2 * math.acos(max(-1.0, 1 - arc_chord_mm / radius)) if arc_chord_mm < radius else math.pi / 2
    n = max(1, math.ceil(abs(sweep) / step))
    out: list[list[float]] = []
    for k in range(1, n + 1):
        t = k / n
        a = a0 + sweep * t
        out.append([cx + radius * math.cos(a), cy + radius * math.sin(a), start[2] + t * (end[2] - start[2]),
                    start[3] + t * (end[3] - start[3])])
    out[-1][:2] = [ex, ey]
    return out


def scan_lines(text: str, arc_chord_mm: float = 0.001) -> Records:
    """The line-by-line reader (every feature; WarpError names a refused line)."""
    pos = [0.0, 0.0, 0.0, 0.0]
    absolute, e_abs, scale, dispensing, feed, plane = True, True, 1.0, False, math.nan, 17.0
    kinds: list[int] = []
    where: list[int] = []
    starts: list[list[float]] = []
    ends: list[list[float]] = []
    feeds: list[float] = []
    eabs: list[bool] = []
    nan4 = [math.nan] * 4
    axes = (("X", 0), ("Y", 1), ("Z", 2), ("E", 3))
    parsed = read_lines(text)

    def add(kind: int, number: int, start: list[float], end: list[float]) -> None:
        kinds.append(kind)
        where.append(number - 1)
        starts.append(start)
        ends.append(end)
        feeds.append(feed)
        eabs.append(e_abs)

    for ln in parsed:
        g, values = ln.g, ln.values
        if ln.m:
            m = set(ln.m)
            dispensing = False if m & DISPENSE_OFF else (True if m & DISPENSE_ON else dispensing)
            e_abs = False if 83.0 in m else (True if 82.0 in m else e_abs)
        if len(g) == 1 and g[0] in (0.0, 1.0, 2.0, 3.0) and any(a in values for a in "XYZEIJ"):
            if "F" in values:
                feed = values["F"] * scale
            start = pos[:]
            for ax, i in axes:
                v = values.get(ax)
                if v is not None:
                    rel = (not absolute) if i < 3 else (not e_abs)
                    pos[i] = pos[i] + v * scale if rel else v * scale
            if g[0] in (2.0, 3.0):
                if plane != 17.0:
                    raise refuse_line(ln.number, ln.text, "arcs are warped in the XY plane (G17) only")
                prev = start
                for point in _arc_points(ln, start, pos, values, scale, g[0] == 2.0, arc_chord_mm):
                    add(_kind(g[0], prev, point, dispensing), ln.number, prev, point)
                    prev = point
                pos = prev[:]
                continue
            add(_kind(g[0], start, pos, dispensing), ln.number, start, pos[:])
            continue
        for code in g:
            if code in (17.0, 18.0, 19.0):
                plane = code
            if code == 92.0:
                raise refuse_line(ln.number, ln.text, "G92 (set position) is not supported by the warp")
            if code in (20.0, 21.0):
                scale = 25.4 if code == 20.0 else 1.0
            elif code in (90.0, 91.0):
                absolute = code == 90.0
        add(MODE if g and all(c in MODE_CODES for c in g) else OTHER, ln.number, nan4, nan4)
    n = len(kinds)
    return Records(np.array(kinds, dtype=np.int8), np.array(where, dtype=np.int64),
                   np.array(starts, float).reshape(n, 4), np.array(ends, float).reshape(n, 4),
                   np.array(feeds, float), np.array(eabs, bool), [ln.text for ln in parsed])


def _ffill(values: npt.NDArray[np.float64], is_set: npt.NDArray[np.bool_], initial: float) -> npt.NDArray[np.float64]:
    """values where is_set, else the last set value before (``initial`` before the first)."""
    idx = np.where(is_set, np.arange(len(values)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], initial)


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
    lines add v; summed in program order exactly as the line-by-line reader does."""
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


def _scan_fast(text: str) -> Records | None:
    """The vectorised reader, or None when the program needs the line-by-line one."""
    if "\r" in text:
        text = text.replace("\r\n", "\n")
        if "\r" in text:
            return None
    if _UNUSUAL.search(text):
        return None
    lines = text.splitlines()
    n_lines = len(lines)
    if not _PLAIN.fullmatch(text):
        return None
    body = _COMMENT.sub("", text).encode("ascii")
    if _EXPONENT.search(body):
        return None                                   # "X1E5": the line-by-line reader decides
    marks = np.frombuffer(body, np.uint8)
    marks = marks[_KEEP[marks]]                       # every word's letter, and the line breaks
    words = int(np.count_nonzero(marks != 10))
    # every word's number, in order (no words: nothing to parse, fromstring would invent one)
    value = np.fromstring(body.translate(_LETTERS_TO_BLANK), sep=" ") if words else np.zeros(0)
    is_nl = marks == 10
    tok_line = (np.cumsum(is_nl) - is_nl)[~is_nl]
    code = marks[~is_nl].astype(np.int64)
    code = np.where(code >= 97, code - 32, code)
    if len(code) != len(value):
        return None
    g_tok, m_tok = code == ord("G"), code == ord("M")
    if np.isin(value[g_tok], (2.0, 3.0, 92.0)).any():
        return None                                         # arcs and G92: the line-by-line reader
    g_count = np.bincount(tok_line[g_tok], minlength=n_lines)
    has: dict[str, npt.NDArray[np.bool_]] = {}
    first: dict[str, npt.NDArray[np.float64]] = {}
    for ch in "XYZEFIJ":
        has[ch], first[ch] = _first_per_line(code == ord(ch), tok_line, value, n_lines)
    g_has, g_first = _first_per_line(g_tok, tok_line, value, n_lines)
    motion = (g_count == 1) & np.isin(g_first, (0.0, 1.0)) & (
        has["X"] | has["Y"] | has["Z"] | has["E"] | has["I"] | has["J"])
    # M codes: a line's events (stop beats start, M83 beats M82)
    m_line, m_val = tok_line[m_tok], value[m_tok]
    off = np.zeros(n_lines, bool)
    on, rel_e, abs_e = off.copy(), off.copy(), off.copy()
    off[m_line[np.isin(m_val, list(DISPENSE_OFF))]] = True
    on[m_line[np.isin(m_val, list(DISPENSE_ON))]] = True
    rel_e[m_line[m_val == 83.0]] = True
    abs_e[m_line[m_val == 82.0]] = True
    dispensing = _ffill(np.where(off, 0.0, 1.0), off | on, 0.0) > 0.5
    e_abs = _ffill(np.where(rel_e, 0.0, 1.0), rel_e | abs_e, 1.0) > 0.5
    # G modes on non-motion lines, the last code of a line winning (tokens in order)
    g_line, g_val = tok_line[g_tok], value[g_tok]
    mode_tok = ~motion[g_line]
    unit = mode_tok & np.isin(g_val, (20.0, 21.0))
    dist = mode_tok & np.isin(g_val, (90.0, 91.0))
    scale_set, absolute_set = np.zeros(n_lines, bool), np.zeros(n_lines, bool)
    scale_v, absolute_v = np.ones(n_lines), np.ones(n_lines)
    scale_set[g_line[unit]] = True
    scale_v[g_line[unit]] = np.where(g_val[unit] == 20.0, 25.4, 1.0)      # fancy assignment: last wins
    absolute_set[g_line[dist]] = True
    absolute_v[g_line[dist]] = np.where(g_val[dist] == 90.0, 1.0, 0.0)
    scale = _ffill(scale_v, scale_set, 1.0)
    absolute = _ffill(absolute_v, absolute_set, 1.0) > 0.5
    mv = np.flatnonzero(motion)
    ends = np.empty((len(mv), 4))
    for i, ch in enumerate("XYZE"):
        given, v = has[ch][mv], first[ch][mv] * scale[mv]
        rel = ~(absolute[mv] if i < 3 else e_abs[mv])
        ends[:, i] = _axis(given & ~rel, given & rel, v)
    starts = np.vstack([np.zeros((1, 4)), ends[:-1]])
    moved_xy = (ends[:, 0] != starts[:, 0]) | (ends[:, 1] != starts[:, 1])
    de = ends[:, 3] - starts[:, 3]
    kind_mv = np.where(moved_xy & (g_first[mv] != 0.0) & ((de > 0) | dispensing[mv]), PRINT,
                       np.where(moved_xy, TRAVEL, np.where(ends[:, 2] != starts[:, 2], ZONLY,
                                                            np.where(de != 0, EONLY, OTHER))))
    only_modes = np.ones(n_lines, bool)
    only_modes[g_line[~np.isin(g_val, list(MODE_CODES))]] = False
    kind = np.where(g_has & only_modes, MODE, OTHER).astype(np.int8)
    kind[mv] = kind_mv
    start, end = np.full((n_lines, 4), math.nan), np.full((n_lines, 4), math.nan)
    start[mv], end[mv] = starts, ends
    feed_line = np.zeros(n_lines, bool)
    feed_line[mv[has["F"][mv]]] = True
    feeds = _ffill(first["F"] * scale, feed_line, math.nan)
    return Records(kind, np.arange(n_lines, dtype=np.int64), start, end, feeds, e_abs, lines)
