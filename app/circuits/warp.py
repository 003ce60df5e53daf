"""Warping an existing G-code program onto a measured surface (bed-mesh style, but proved).

Every printing move (a G0/G1 feed move that extrudes, or that runs while the dispenser is
on) is moved onto the surface: z = h(x, y) + ``standoff_mm`` (or, without a standoff, the
program's own z + h(x, y), Klipper's convention); it is split into n equal top-view pieces
with n the smallest count for which the PROVED bound L^2 / (8 n^2) * K <= ``chord_error_mm``
holds (K: the height field's curvature bound along the move, see
:mod:`app.circuits.heightfield`).  Klipper's bed mesh and bCNC's autolevel split at a fixed
length instead (:func:`fixed_split_error` measures what that leaves).  Extrusion (E) is
shared out along the pieces (absolute or relative).  Travel moves run at
``safe_z_mm`` (default: the surface's highest point + ``clearance_mm``): a lift before the
first travel move after printing, a descent to the next print's start.  A printing move
outside the measured region is refused (WarpError naming the line) unless
``allow_outside`` (the edge height is then held).  Arcs (G2/G3, XY plane) are first split
into chords within ``arc_chord_mm`` of the arc (top view), then warped like lines.
Output: absolute mm (``G21``, ``G90``) whatever the input's units and modes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from app.circuits.gcode_scan import EONLY, OTHER, PRINT, TRAVEL, ZONLY, MODE, Records, scan_program
from app.circuits.heightfield import HeightField, Inside
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = ["WarpOptions", "WarpResult", "warp_program", "check_program", "check_region", "fixed_split_error"]


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
class WarpResult:
    """text: the warped program; lines_in (records read: a source line, or an arc's chord) /
    lines_out; printing_moves; pieces (emitted printing segments); max_bound_mm: the largest
    proved chord bound of an emitted piece (<= chord_error_mm)."""

    text: str
    lines_in: int
    lines_out: int
    printing_moves: int
    pieces: int
    max_bound_mm: float
    safe_z_mm: float


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
    n, piece_bound, seg, first, k, pts, z = pieces
    h_start = surface.height(p0[:, 0], p0[:, 1]) if len(p0) else np.zeros(0)
    z_start = h_start + opts.standoff_mm if opts.standoff_mm is not None else p0[:, 2] + h_start
    tops = end[:, 2][np.isfinite(end[:, 2])]
    program_top = float(tops.max()) if len(tops) else 0.0
    safe_z = opts.safe_z_mm if opts.safe_z_mm is not None else float(surface.z.max()) + opts.clearance_mm + (
        0.0 if opts.standoff_mm is not None else max(program_top, 0.0))
    # where the pen is before each print / travel record, and whether it is lifted
    moving = np.flatnonzero((kind == PRINT) | (kind == TRAVEL))
    prev = np.concatenate([[-1], moving[:-1]])
    after_travel = np.concatenate([[False], kind[moving[:-1]] == TRAVEL])
    at = end[np.maximum(prev, 0)]
    moved = (prev < 0) | (np.abs(at[:, 0] - start[moving, 0]) + np.abs(at[:, 1] - start[moving, 1]) > LENGTH_EPS_MM)
    is_print = kind[moving] == PRINT
    p_moved, p_lift = moved[is_print], (after_travel | moved)[is_print]
    t_lift = ~after_travel[~is_print]
    count = np.ones(len(kind), np.int64)
    count[k_print] = p_moved.astype(np.int64) + p_lift + n
    count[moving[~is_print]] = 1 + t_lift
    slot = np.concatenate([[0], np.cumsum(count)[:-1]])
    out = np.empty(int(count.sum()), dtype=object)
    templates, values = _piece_template(recs, k_print, pieces, d)
    out[np.repeat(slot[k_print] + p_moved + p_lift, n) + k - 1] = templates

    def esc(line: str) -> str:
        return line.replace("%", "%%") + "\n"

    feed = recs.feed
    for j in np.flatnonzero(p_moved | p_lift):                     # a print's approach lines
        i, s = k_print[j], slot[k_print[j]]
        if p_moved[j]:
            out[s] = esc(f"G0 X{_fmt(start[i, 0], d)} Y{_fmt(start[i, 1], d)}")
        f = feed[i]
        out[s + p_moved[j]] = esc(f"G1 Z{_fmt(z_start[j], d)}" + (f" F{_fmt(f, 1)}" if f == f and f else ""))
    travel = moving[~is_print]
    for t, i in enumerate(travel):
        s = slot[i]
        if t_lift[t]:
            out[s] = esc(f"G0 Z{_fmt(safe_z, d)}")
        e_word = f" E{_fmt(end[i, 3], 5)}" if end[i, 3] != start[i, 3] and recs.e_abs[i] else ""
        out[s + t_lift[t]] = esc(f"G0 X{_fmt(end[i, 0], d)} Y{_fmt(end[i, 1], d)}" + e_word)
    for i in np.flatnonzero((kind != PRINT) & (kind != TRAVEL)):
        line = recs.lines[recs.line[i]]
        if kind[i] in (ZONLY, MODE):
            out[slot[i]] = esc(f"; {line.strip()}  (the warp sets Z and absolute mm)")
        elif kind[i] == EONLY:
            e_val = end[i, 3] if recs.e_abs[i] else end[i, 3] - start[i, 3]
            f = feed[i]
            out[slot[i]] = esc(f"G1 E{_fmt(e_val, 5)}" + (f" F{_fmt(f, 1)}" if f == f and f else ""))
        else:
            assert kind[i] == OTHER
            out[slot[i]] = esc(line.rstrip())
    text_out = "; warped onto a measured surface by conforma (absolute mm)\nG21\nG90\n" + \
        "".join(out.tolist()) % tuple(values)
    return WarpResult(text_out, len(kind), len(out) + 3, len(k_print), int(n.sum()),
                      float(piece_bound.max(initial=0.0)), float(safe_z))


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
