"""Warping an existing G-code program onto a measured surface (bed-mesh style, with a chord bound).

The program is read by :func:`app.circuits.gcode_scan.scan_program` (the one G-code reader's
moves; what the warp does not model is refused naming the line).  Every printing move (a
G1/G2/G3 move in x/y that extrudes, or that runs while the dispenser is on) is moved onto the
surface: z = h(x, y) + ``standoff_mm`` (or, without a standoff, the program's own z + h(x, y),
Klipper's convention); it is split into n equal top-view pieces with n the smallest count for
which the bound L^2 / (8 n^2) * K <= ``chord_error_mm`` holds (K: the height field's curvature
bound along the move, see :mod:`app.circuits.heightfield`).  Klipper's bed mesh and bCNC's
autolevel split at a fixed length instead (:func:`fixed_split_error` measures what that
leaves).  Extrusion (E) is shared out along the pieces (absolute or relative).

Every other move keeps its place, code and feed, its z relative to the surface under it: a
Z-only or repeated move goes to the program's z + h(x, y) (with a standoff, the printing height
+ the program's height above its next printing move's z).  Travel moves run at the safe height
(``safe_z_mm``, at least the surface's highest point + ``clearance_mm``; by default that + the
highest printing height above the surface): a lift before a travel or homing move from below
it, a descent to a printing move's start when the tool is elsewhere (with the travel's code and
feed after a travel).  Until the tool's x/y is known (the program's start, after a homing
move) a Z-only move is held at least at the safe height and a printing move is approached
from it.  Outside the measured region a printing move is refused (WarpError naming
the line) and a Z-only move is held at the safe height, unless ``allow_outside`` (the edge
height is then held).  Output: absolute mm (``G21``, ``G90``) in machine coordinates whatever
the input's units, modes and ``G92`` shifts.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from app.circuits.errors import WarpError
from app.circuits.gcode_scan import EONLY, MODE, OTHER, PRINT, STILL, TRAVEL, ZONLY, Records, scan_program
from app.circuits.heightfield import HeightField, Inside

__all__ = ["WarpFigures", "WarpOptions", "WarpResult", "warp_program", "check_program", "check_region",
           "fixed_split_error"]


@dataclass(frozen=True)
class WarpOptions:
    standoff_mm: float | None = None
    chord_error_mm: float = 0.002
    clearance_mm: float = 2.0
    arc_chord_mm: float = 0.001
    safe_z_mm: float | None = None
    allow_outside: bool = False
    decimals: int = 4


@dataclass(frozen=True)
class WarpFigures:
    """What a warp wrote: lines_in (records read: a source line, or an arc's chord) / lines_out;
    printing_moves; pieces (emitted printing segments); max_chord_bound_mm: the largest chord
    bound of an emitted piece (<= chord_error_mm), proved against the height field, not the
    part (how far the field is from the part is the height model's own error); safe_z_mm: the
    travel height (mm)."""

    lines_in: int
    lines_out: int
    printing_moves: int
    pieces: int
    max_chord_bound_mm: float
    safe_z_mm: float


@dataclass(frozen=True)
class WarpResult(WarpFigures):
    """The warped program (``text``) and its figures (:class:`WarpFigures`)."""

    text: str


def _fmt(v: float, d: int) -> str:
    s = f"{v:.{d}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def check_program(text: str, surface: HeightField, allow_outside: bool = False) -> int:
    """Raise WarpError naming the first refused line (arcs outside XY, G92, a printing move
    outside the measured region unless allowed); returns the number of printing moves."""
    recs = scan_program(text)
    if not allow_outside:
        check_region(recs, surface.inside)
    return int(np.count_nonzero(recs.kind == PRINT))


def check_region(recs: Records, inside: Inside, bounds: tuple[float, float, float, float] | None = None) -> None:
    """WarpError naming the first printing move with an end where ``inside(x (n,), y (n,)) -> (n,)
    bool`` is False (``bounds`` (x0, x1, y0, y1) mm named in the message when given)."""
    k_print = np.flatnonzero(recs.kind == PRINT)
    if not len(k_print):
        return
    p0, p1 = recs.start[k_print], recs.end[k_print]
    ok = inside(p0[:, 0], p0[:, 1]) & inside(p1[:, 0], p1[:, 1])
    if ok.all():
        return
    k = int(np.argmin(ok))
    where = "" if bounds is None else (f" (x {bounds[0]:.3f}..{bounds[1]:.3f}, y {bounds[2]:.3f}.."
                                       f"{bounds[3]:.3f})")
    err = recs.refuse(int(k_print[k]), f"the printing move from x={p0[k, 0]:.4f}, y={p0[k, 1]:.4f} to "
                      f"x={p1[k, 0]:.4f}, y={p1[k, 1]:.4f} leaves the measured region{where}")
    err.value.update({"from_xy": [round(float(v), 4) for v in p0[k, :2]],
                      "to_xy": [round(float(v), 4) for v in p1[k, :2]]})
    raise err


def _refuse_outside(recs: Records, surface: HeightField) -> None:
    """WarpError for the first printing move leaving the height field's measured region."""
    check_region(recs, surface.inside, (surface.x[0], surface.x[-1], surface.y[0], surface.y[-1]))


class _Pieces(NamedTuple):
    """The printing moves (m,) cut into N pieces: ``n`` (m,) pieces per move, ``piece_bound`` (m,) mm
    the proved chord error of each of its pieces; per piece: ``seg`` (N,) its move, ``k`` (N,) its
    1-based index in the move, ``pts`` (N, 4) its end, ``z`` (N,) mm its warped height;
    ``first`` (m,) the index of each move's first piece."""

    n: npt.NDArray[np.int64]
    piece_bound: npt.NDArray[np.float64]
    seg: npt.NDArray[np.int64]
    first: npt.NDArray[np.int64]
    k: npt.NDArray[np.int64]
    pts: npt.NDArray[np.float64]
    z: npt.NDArray[np.float64]


def _pieces(p0: npt.NDArray[np.float64], p1: npt.NDArray[np.float64], surface: HeightField,
            opts: WarpOptions) -> _Pieces:
    """Per printing move (m,): piece count n, proved piece bound; every piece end (N, 4) and its z (N,)."""
    length = np.hypot(p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1])
    bound = surface.curvature_bound(p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1]) if len(p0) else np.zeros(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.where(bound > 0, np.ceil(length * np.sqrt(bound / (8.0 * opts.chord_error_mm))), 1.0)
    n = np.maximum(n, 1).astype(np.int64)
    piece_bound = (length / n) ** 2 / 8.0 * bound
    seg = np.repeat(np.arange(len(p0), dtype=np.int64), n)
    first = (np.cumsum(n) - n).astype(np.int64)
    k = np.arange(n.sum(), dtype=np.int64) - first[seg] + 1
    t = k / n[seg]
    pts = p0[seg] + t[:, None] * (p1 - p0)[seg]
    h = surface.height(pts[:, 0], pts[:, 1]) if len(pts) else np.zeros(0)
    z = h + opts.standoff_mm if opts.standoff_mm is not None else pts[:, 2] + h
    return _Pieces(n, piece_bound, seg, first, k, pts, z)


def _piece_template(recs: Records, k_print: npt.NDArray[np.int64], pieces: _Pieces,
                    d: int) -> tuple[npt.NDArray[np.object_], list[float]]:
    """Each piece's line as a %-template (N,) and all their values in order (vectorised: E
    shared out absolute or relative, F on a move's first piece)."""
    n, seg, first, k, pts, z = pieces.n, pieces.seg, pieces.first, pieces.k, pieces.pts, pieces.z
    e0, e1 = recs.start[k_print, 3][seg], recs.end[k_print, 3][seg]
    e_abs = recs.e_abs[k_print][seg]
    # relative E: rounding the running total (not each share) keeps the program's total exact
    total = np.cumsum(np.where(e_abs, 0.0, (e1 - e0) / n[seg]))
    share = np.round(total, 5) - np.round(np.concatenate([[0.0], total[:-1]]), 5)
    e = np.where(e_abs, e0 + k / n[seg] * (e1 - e0), share)
    feed = recs.feed[k_print]
    has_f = np.zeros(len(seg), bool)
    has_f[first] = np.isfinite(feed) & (feed != 0)
    has_e = e1 != e0
    values = np.column_stack([pts[:, 0], pts[:, 1], z, e, np.repeat(np.nan_to_num(feed), n)])
    mask = np.column_stack([np.ones((len(seg), 3), bool), has_e, has_f])
    base = f"G1 X%.{d}f Y%.{d}f Z%.{d}f"
    templates = np.array([base + "\n", base + " F%.1f\n", base + " E%.5f\n", base + " E%.5f F%.1f\n"], object)
    chosen: npt.NDArray[np.object_] = templates[has_e * 2 + has_f]
    return chosen, values[mask].tolist()


def _z_work(recs: Records) -> npt.NDArray[np.float64]:
    """(n,) mm: the program's z at the start of the next printing move (the last one's after
    it, 0 without any): the program height the standoff replaces."""
    k_print = np.flatnonzero(recs.kind == PRINT)
    n = len(recs.kind)
    if not len(k_print):
        return np.zeros(n)
    nxt = np.searchsorted(k_print, np.arange(n))
    z: npt.NDArray[np.float64] = recs.start[k_print[np.minimum(nxt, len(k_print) - 1)], 2]
    return z


def _safe_z(surface: HeightField, print_rel: npt.NDArray[np.float64], opts: WarpOptions) -> float:
    """The travel height (mm): above the part's highest measured point by ``clearance_mm`` plus
    the highest printing height above the surface, or ``safe_z_mm`` when it is at least that."""
    floor = float(surface.z.max()) + opts.clearance_mm
    auto = floor + max(float(print_rel.max(initial=0.0)), 0.0)
    if opts.safe_z_mm is None:
        return auto
    if not opts.safe_z_mm >= floor:
        raise WarpError(f"safe_z_mm {opts.safe_z_mm:g} is below the part's highest point {surface.z.max():.4f} mm "
                        f"+ clearance {opts.clearance_mm:g} mm", field="safe_z_mm", value=opts.safe_z_mm)
    return float(opts.safe_z_mm)


def warp_program(text: str, surface: HeightField, opts: WarpOptions = WarpOptions()) -> WarpResult:
    """The warped program (see the module doc); WarpError names a refused line."""
    recs = scan_program(text, opts.arc_chord_mm)
    kind, start, end = recs.kind, recs.start, recs.end
    k_print = np.flatnonzero(kind == PRINT)
    if not opts.allow_outside:
        _refuse_outside(recs, surface)
    d = opts.decimals
    p0, p1 = start[k_print], end[k_print]
    pieces = _pieces(p0, p1, surface, opts)
    n, piece_bound = pieces.n, pieces.piece_bound
    h_start = surface.height(p0[:, 0], p0[:, 1]) if len(p0) else np.zeros(0)
    z_start = h_start + opts.standoff_mm if opts.standoff_mm is not None else p0[:, 2] + h_start
    # every other move's z: the program's, relative to the surface under it
    delta = opts.standoff_mm - _z_work(recs) if opts.standoff_mm is not None else np.zeros(len(kind))
    print_rel = np.full(len(k_print), float(opts.standoff_mm)) if opts.standoff_mm is not None else \
        np.maximum(p0[:, 2], p1[:, 2])
    safe_z = _safe_z(surface, print_rel, opts)
    k_z = np.flatnonzero((kind == ZONLY) | (kind == STILL))
    z_move = np.full(len(kind), np.nan)
    if len(k_z):
        xz, yz = end[k_z, 0], end[k_z, 1]
        z_move[k_z] = surface.height(xz, yz) + end[k_z, 2] + delta[k_z]
        if not opts.allow_outside:                # where the part is unknown, never below the safe height
            unknown = ~surface.inside(xz, yz)
            z_move[k_z[unknown]] = np.maximum(z_move[k_z[unknown]], safe_z)
    templates, values = _piece_template(recs, k_print, pieces, d)
    z_end = pieces.z[pieces.first + n - 1] if len(n) else np.zeros(0)
    parts, marks, run_first, run_last = _write(recs, z_move, z_start, z_end, safe_z, d)
    # each run of printing moves: its pieces, contiguous, in place of its mark
    piece_end = np.cumsum(n)
    run_pieces = piece_end[run_last] - (piece_end[run_first] - n[run_first]) if len(marks) else np.zeros(0, np.int64)
    expand = np.ones(len(parts), np.int64)
    expand[marks] = run_pieces
    slot = np.cumsum(expand) - expand
    out = np.empty(int(expand.sum()), dtype=object)
    keep = np.ones(len(parts), bool)
    keep[marks] = False
    out[slot[keep]] = np.array(parts, dtype=object)[keep]
    out[np.repeat(slot[marks] - np.concatenate([[0], np.cumsum(run_pieces)[:-1]]), run_pieces)
        + np.arange(int(run_pieces.sum()))] = templates
    body: list[str] = out.tolist()
    text_out = "; warped onto a measured surface by conforma (absolute mm)\nG21\nG90\n" + \
        "".join(body) % tuple(values)
    return WarpResult(text=text_out, lines_in=len(kind), lines_out=len(out) + 3, printing_moves=len(k_print),
                      pieces=int(n.sum()), max_chord_bound_mm=float(piece_bound.max(initial=0.0)),
                      safe_z_mm=float(safe_z))


def _write(recs: Records, z_move: npt.NDArray[np.float64], z_start: npt.NDArray[np.float64],
           z_end: npt.NDArray[np.float64], safe_z: float,
           d: int) -> tuple[list[str], npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Every output line but the printing pieces (``%``-escaped), in order; the index in it of
    each run of printing moves' mark (where their pieces go) and the run's first and last
    printing move.  Walks the records once (a run of printing moves that continue one another
    as one step), keeping where the tool is: a lift to ``safe_z`` before a travel or homing
    move from below it, a descent to a printing move's start when the tool is not there (with
    the travel's own code and feed after a travel), every Z-only and repeated move at its own
    place, code and feed."""
    kind_a = recs.kind
    tol = 0.5 * 10.0 ** -d
    is_print = kind_a == PRINT
    k_print = np.flatnonzero(is_print)
    # a printing move continues the one before it: the record just before, ending where it starts
    cont = np.zeros(len(k_print), bool)
    if len(k_print) > 1:
        cont[1:] = (np.diff(k_print) == 1) & (np.abs(z_start[1:] - z_end[:-1]) <= tol)
    head = ~is_print
    head[k_print[~cont]] = True
    if recs.carried:                                      # a line with words to carry starts a step
        has_words = np.zeros(len(recs.lines), bool)
        has_words[list(recs.carried)] = True
        first_of_line = np.concatenate([[True], recs.line[1:] != recs.line[:-1]])
        head |= has_words[recs.line] & first_of_line
    hd = np.flatnonzero(head)
    heads = hd.tolist()
    print_index = np.cumsum(is_print) - 1                 # record -> its index among the printing moves
    last_rec = np.concatenate([hd[1:], [len(kind_a)]]) - 1 if len(hd) else hd   # each step's last record
    # every column at the steps only (a run of printing moves is one step)
    kind, line, motion, feed, e_abs = (recs.kind[hd].tolist(), recs.line[hd].tolist(), recs.motion[hd].tolist(),
                                       recs.feed[hd].tolist(), recs.e_abs[hd].tolist())
    x1, y1 = recs.end[hd, 0].tolist(), recs.end[hd, 1].tolist()
    x0, y0 = recs.start[hd, 0].tolist(), recs.start[hd, 1].tolist()
    e0, e1 = recs.start[hd, 3].tolist(), recs.end[hd, 3].tolist()
    line_last = recs.line[last_rec].tolist()
    p_first = np.maximum(print_index[hd], 0)
    p_last = np.maximum(print_index[last_rec], 0)
    pf, pl = p_first.tolist(), p_last.tolist()
    zm = z_move[hd].tolist()
    zs = z_start[p_first].tolist() if len(z_start) else [math.nan] * len(heads)
    ze = z_end[p_last].tolist() if len(z_end) else [math.nan] * len(heads)
    lines, carried = recs.lines, recs.carried
    lift = f"G0 Z{_fmt(safe_z, d)}\n"
    parts: list[str] = []
    marks: list[int] = []
    run_first: list[int] = []
    run_last: list[int] = []
    z_now = math.nan                   # the tool's height in the output (NaN: unknown)
    xy_known = False                   # where the tool is in x/y (not before the first x/y move)
    after: tuple[int | None, float] = (None, math.nan)   # code and feed of a travel just made
    last_line = -1

    def words(i: int) -> str:
        """The E and F words of record i (E in the output's mode, F for a feed move)."""
        out = ""
        if e1[i] != e0[i]:
            out += f" E{_fmt(e1[i] if e_abs[i] else e1[i] - e0[i], 5)}"
        f = feed[i]
        if motion[i] != 0 and f == f and f:
            out += f" F{_fmt(f, 1)}"
        return out

    for i in range(len(heads)):
        k, ln = kind[i], line[i]
        if ln != last_line:
            last_line = ln
            extra = carried.get(ln)
            if extra:
                parts.append(extra.replace("%", "%%") + "\n")
        if k == OTHER:
            parts.append(lines[ln].rstrip().replace("%", "%%") + "\n")
        elif k == MODE:
            parts.append(f"; {lines[ln].strip()}  (the warp writes absolute mm)".replace("%", "%%") + "\n")
        elif k == PRINT:
            if not xy_known:                   # the program's start or a homing: go to the print's start
                if not z_now >= safe_z - tol:
                    parts.append(lift)
                parts.append(f"G0 X{_fmt(x0[i], d)} Y{_fmt(y0[i], d)}\n")
                z_now, xy_known = safe_z, True
            if not abs(z_now - zs[i]) <= tol:
                code, f = (after[0], after[1]) if after[0] is not None else (1, feed[i])
                parts.append(f"G{code} Z{_fmt(zs[i], d)}" + (f" F{_fmt(f, 1)}" if code and f == f and f else "") + "\n")
            last_line = line_last[i]
            marks.append(len(parts))
            parts.append("")
            run_first.append(pf[i])
            run_last.append(pl[i])
            z_now = ze[i]
            after = (None, math.nan)
        elif k == TRAVEL:
            if not z_now >= safe_z - tol:
                parts.append(lift)
                z_now = safe_z
            code = motion[i] if motion[i] in (0, 1) else 1
            parts.append(f"G{code} X{_fmt(x1[i], d)} Y{_fmt(y1[i], d)}" + words(i) + "\n")
            xy_known = True
            after = (code, feed[i])
        elif k in (ZONLY, STILL):
            z = zm[i] if xy_known else max(zm[i], safe_z)     # where the tool is unknown: not below safe
            code = motion[i] if motion[i] in (0, 1) else 1
            parts.append(f"G{code} Z{_fmt(z, d)}" + words(i) + "\n")
            z_now = z
            after = (None, math.nan)
        elif k == EONLY:
            parts.append("G1" + words(i) + "\n")
        else:                                                   # HOME_KIND
            if not z_now >= safe_z - tol:
                parts.append(lift)
            axes = sorted(_named(lines[ln]))
            parts.append(("G91 G28 " + " ".join(f"{ax}0" for ax in axes) + "\nG90\n") if axes else "G28\n")
            z_now, xy_known = math.nan, False
            after = (None, math.nan)
    return parts, np.array(marks, np.int64), np.array(run_first, np.int64), np.array(run_last, np.int64)


def _named(text: str) -> set[str]:
    """The axes a G28 line names ("G28 X", "G28 Z0"; none: all)."""
    body = text.split(";", 1)[0].upper()
    body = re.sub(r"\([^)]*\)", " ", body)
    body = re.sub(r"G\s*28(?![\d.])", " ", body)
    return {ax for ax in "XYZ" if ax in body}


def fixed_split_error(text: str, surface: HeightField, split_mm: float, standoff_mm: float,
                      samples_per_piece: int = 16) -> tuple[int, float]:
    """(printing pieces, worst |z error| mm) when printing moves are split every ``split_mm``
    (Klipper's bed mesh / bCNC), measured against the surface at ``samples_per_piece`` points per piece."""
    recs = scan_program(text)
    k_print = np.flatnonzero(recs.kind == PRINT)
    if not len(k_print):
        return 0, 0.0
    p0, p1 = recs.start[k_print], recs.end[k_print]
    length = np.hypot(p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1])
    n = np.maximum(1, np.ceil(length / split_mm)).astype(np.int64)
    seg = np.repeat(np.arange(len(k_print)), n)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    k = np.arange(n.sum()) - first[seg]
    ta, tb = k / n[seg], (k + 1) / n[seg]
    s = np.linspace(0.0, 1.0, samples_per_piece + 1)[1:-1]
    tt = ta[:, None] + s[None, :] * (tb - ta)[:, None]
    xy = p0[seg, None, :2] + tt[..., None] * (p1 - p0)[seg, None, :2]
    za = surface.height(*(p0[seg, :2] + ta[:, None] * (p1 - p0)[seg, :2]).T)
    zb = surface.height(*(p0[seg, :2] + tb[:, None] * (p1 - p0)[seg, :2]).T)
    chord = za[:, None] + s[None, :] * (zb - za)[:, None]
    true = surface.height(xy[..., 0].ravel(), xy[..., 1].ravel()).reshape(chord.shape)
    return int(n.sum()), float(np.abs(true - chord).max())
