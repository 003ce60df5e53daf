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

import math

import numpy as np

from app.circuits.errors import WarpError
from app.circuits.heightfield import HeightField
from app.gcode.lines import read_lines

__all__ = ["WarpOptions", "WarpResult", "warp_program", "check_program", "fixed_split_error"]

DISPENSE_ON = frozenset({"M106", "M8", "M3", "M4", "M7"})
DISPENSE_OFF = frozenset({"M107", "M9", "M5"})


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
    """text: the warped program; lines_in / lines_out; printing_moves; pieces (emitted printing
    segments); max_bound_mm: the largest proved chord bound of an emitted piece (<= chord_error_mm)."""

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


def _refuse(ln, message: str) -> WarpError:
    return WarpError(f"line {ln.number}: {message}", field="file",
                     value={"line": ln.number, "text": ln.text.strip()[:80]})


def _arc_points(ln, start: list, end: list, values: dict, scale: float, clockwise: bool,
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
        if chord == 0.0 or abs(r) < chord / 2 - 1e-9:
            raise _refuse(ln, f"the arc's radius {abs(r):g} mm cannot join its ends {chord:g} mm apart")
        h = math.sqrt(max(r * r - chord * chord / 4, 0.0)) * (1 if (r > 0) != clockwise else -1)
        cx, cy = sx + dx / 2 - h * dy / chord, sy + dy / 2 + h * dx / chord
    else:
        raise _refuse(ln, "an arc needs I/J or R")
    radius = math.hypot(sx - cx, sy - cy)
    if radius <= 0.0:
        raise _refuse(ln, "the arc has zero radius")
    a0, a1 = math.atan2(sy - cy, sx - cx), math.atan2(ey - cy, ex - cx)
    ccw = (a1 - a0) % (2 * math.pi)
    if abs(ex - sx) + abs(ey - sy) <= 1e-12:
        ccw = 2 * math.pi
    sweep = -(2 * math.pi - ccw if ccw < 2 * math.pi else 2 * math.pi) if clockwise else (ccw or 2 * math.pi)
    step = 2 * math.acos(max(-1.0, 1 - arc_chord_mm / radius)) if arc_chord_mm < radius else math.pi / 2
    n = max(1, math.ceil(abs(sweep) / step))
    out = []
    for k in range(1, n + 1):
        t = k / n
        a = a0 + sweep * t
        out.append([cx + radius * math.cos(a), cy + radius * math.sin(a), start[2] + t * (end[2] - start[2]),
                    start[3] + t * (end[3] - start[3])])
    out[-1][:2] = [ex, ey]
    return out


def _kind(g0: float, start: list, end: list, dispensing: bool) -> str:
    moved_xy = end[0] != start[0] or end[1] != start[1]
    de = end[3] - start[3]
    if moved_xy and g0 != 0.0 and (de > 0 or dispensing):
        return "print"
    if moved_xy:
        return "travel"
    if end[2] != start[2]:
        return "zonly"
    return "eonly" if de != 0 else "other"


def _scan(text: str, arc_chord_mm: float = 0.001):
    """First pass: modal interpretation.  Returns per-line records
    (kind, line, start [x, y, z, e], end [x, y, z, e], feed mm/min, e absolute) with kind in
    print / travel / zonly / eonly / mode / other (start, end None for the last two).  Arcs
    (G2/G3, XY plane) become several records of their line, chords within ``arc_chord_mm``."""
    pos = [0.0, 0.0, 0.0, 0.0]
    absolute, e_abs, scale, dispensing, feed, plane = True, True, 1.0, False, None, 17.0
    recs = []
    axes = (("X", 0), ("Y", 1), ("Z", 2), ("E", 3))
    for ln in read_lines(text):
        g, values = ln.g, ln.values
        if ln.m:
            m = {f"M{int(v)}" for v in ln.m}
            if m & DISPENSE_ON:
                dispensing = True
            if m & DISPENSE_OFF:
                dispensing = False
            if "M82" in m:
                e_abs = True
            if "M83" in m:
                e_abs = False
        if g and (g[0] in (0.0, 1.0, 2.0, 3.0)) and len(g) == 1 and (
                "X" in values or "Y" in values or "Z" in values or "E" in values or "I" in values or "J" in values):
            if "F" in values:
                feed = values["F"] * scale
            start = pos[:]
            for ax, i in axes:
                v = values.get(ax)
                if v is None:
                    continue
                rel = (not absolute) if i < 3 else (not e_abs)
                pos[i] = pos[i] + v * scale if rel else v * scale
            if g[0] in (2.0, 3.0):
                if plane != 17.0:
                    raise _refuse(ln, "arcs are warped in the XY plane (G17) only")
                prev = start
                for point in _arc_points(ln, start, pos, values, scale, g[0] == 2.0, arc_chord_mm):
                    recs.append((_kind(g[0], prev, point, dispensing), ln, prev, point, feed, e_abs))
                    prev = point
                pos = prev[:]
                continue
            recs.append((_kind(g[0], start, pos, dispensing), ln, start, pos[:], feed, e_abs))
            continue
        for code in g:
            if code in (17.0, 18.0, 19.0):
                plane = code
            if code == 92.0:
                raise _refuse(ln, "G92 (set position) is not supported by the warp")
            if code == 20.0:
                scale = 25.4
            elif code == 21.0:
                scale = 1.0
            elif code == 90.0:
                absolute = True
            elif code == 91.0:
                absolute = False
        kind = "mode" if g and all(c in (17.0, 20.0, 21.0, 90.0, 91.0) for c in g) else "other"
        recs.append((kind, ln, None, None, None, e_abs))
    return recs


def _piece_lines(prints, n: np.ndarray, pts: np.ndarray, z: np.ndarray, d: int) -> list[str]:
    """The G1 line of every emitted piece (vectorised formatting; E shared out, F on the first piece)."""
    seg = np.repeat(np.arange(len(prints)), n)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    k = np.arange(n.sum()) - first[seg] + 1
    e0 = np.array([r[2][3] for r in prints])[seg]
    e1 = np.array([r[3][3] for r in prints])[seg]
    e_abs = np.array([r[5] for r in prints])[seg]
    # relative E: rounding the running total (not each share) keeps the program's total exact
    total = np.cumsum(np.where(e_abs, 0.0, (e1 - e0) / n[seg]))
    share = np.round(total, 5) - np.round(np.concatenate([[0.0], total[:-1]]), 5)
    e = np.where(e_abs, e0 + k / n[seg] * (e1 - e0), share)
    has_e = e1 != e0
    xyz = f"G1 X{{:.{d}f}} Y{{:.{d}f}} Z{{:.{d}f}}".format
    lines = list(map(xyz, pts[:, 0], pts[:, 1], z))
    for j in np.flatnonzero(has_e):
        lines[j] += f" E{e[j]:.5f}"
    for i, r in enumerate(prints):
        if r[4]:
            lines[first[i]] += f" F{r[4]:.1f}"
    return lines


def check_program(text: str, surface: HeightField, allow_outside: bool = False) -> int:
    """Raise WarpError naming the first refused line (arcs, G92, a printing move outside the
    measured region unless allowed); returns the number of printing moves."""
    recs = _scan(text)
    if not allow_outside:
        _refuse_outside([r for r in recs if r[0] == "print"], surface)
    return sum(1 for r in recs if r[0] == "print")


def _refuse_outside(prints: list, surface: HeightField) -> None:
    if not prints:
        return
    p0 = np.array([r[2] for r in prints])
    p1 = np.array([r[3] for r in prints])
    inside = surface.inside(p0[:, 0], p0[:, 1]) & surface.inside(p1[:, 0], p1[:, 1])
    if not inside.all():
        k = int(np.argmin(inside))
        raise _refuse(prints[k][1], f"the printing move from x={p0[k, 0]:.4f}, y={p0[k, 1]:.4f} to "
                      f"x={p1[k, 0]:.4f}, y={p1[k, 1]:.4f} leaves the measured region (x {surface.x[0]:.3f}.."
                      f"{surface.x[-1]:.3f}, y {surface.y[0]:.3f}..{surface.y[-1]:.3f})")


def warp_program(text: str, surface: HeightField, opts: WarpOptions = WarpOptions()) -> WarpResult:
    """The warped program (see the module doc); WarpError names a refused line."""
    recs = _scan(text, opts.arc_chord_mm)
    prints = [r for r in recs if r[0] == "print"]
    p0 = np.array([r[2] for r in prints]).reshape(-1, 4)
    p1 = np.array([r[3] for r in prints]).reshape(-1, 4)
    if not opts.allow_outside:
        _refuse_outside(prints, surface)
    if len(prints):
        length = np.hypot(p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1])
        bound = surface.curvature_bound(p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1])
        with np.errstate(divide="ignore"):
            n = np.where(bound > 0, np.ceil(length * np.sqrt(bound / (8.0 * opts.chord_error_mm))), 1.0)
        n = np.maximum(n, 1).astype(np.int64)
        piece_bound = (length / n) ** 2 / 8.0 * bound
        # all piece end points at once
        seg = np.repeat(np.arange(len(prints)), n)
        first = np.concatenate([[0], np.cumsum(n)[:-1]])
        t = (np.arange(n.sum()) - first[seg] + 1) / n[seg]
        pts = p0[seg] + t[:, None] * (p1 - p0)[seg]
        h = surface.height(pts[:, 0], pts[:, 1])
        z = h + opts.standoff_mm if opts.standoff_mm is not None else pts[:, 2] + h
        h_start = surface.height(p0[:, 0], p0[:, 1])
        z_start = h_start + opts.standoff_mm if opts.standoff_mm is not None else p0[:, 2] + h_start
    else:
        n = np.zeros(0, dtype=np.int64)
        piece_bound = np.zeros(0)
        first = np.zeros(0, dtype=np.int64)
    grid_top = float(surface.z.max())
    program_top = max((r[3][2] for r in recs if r[3] is not None), default=0.0)
    safe_z = opts.safe_z_mm if opts.safe_z_mm is not None else grid_top + opts.clearance_mm + (
        0.0 if opts.standoff_mm is not None else max(program_top, 0.0))
    d = opts.decimals
    piece_lines = _piece_lines(prints, n, pts, z, d) if len(prints) else []
    out = ["; warped onto a measured surface by conforma (absolute mm)", "G21", "G90"]
    lifted, k_print, at = False, 0, None
    for kind, ln, start, end, feed, e_abs in recs:
        if kind == "print":
            k = k_print
            k_print += 1
            moved = at is None or abs(at[0] - start[0]) + abs(at[1] - start[1]) > 1e-9
            if moved:
                out.append(f"G0 X{_fmt(start[0], d)} Y{_fmt(start[1], d)}")
            if lifted or moved:
                out.append(f"G1 Z{_fmt(z_start[k], d)}" + (f" F{_fmt(feed, 1)}" if feed else ""))
                lifted = False
            out.extend(piece_lines[first[k]: first[k] + n[k]])
            at = end
        elif kind == "travel":
            if not lifted:
                out.append(f"G0 Z{_fmt(safe_z, d)}")
                lifted = True
            out.append(f"G0 X{_fmt(end[0], d)} Y{_fmt(end[1], d)}" + (f" E{_fmt(end[3], 5)}" if end[3] != start[3]
                                                                         and e_abs else ""))
            at = end
        elif kind in ("zonly", "mode"):
            out.append(f"; {ln.text.strip()}  (the warp sets Z and absolute mm)")
        elif kind == "eonly":
            out.append(f"G1 E{_fmt(end[3] if e_abs else end[3] - start[3], 5)}" + (f" F{_fmt(feed, 1)}" if feed else ""))
        else:
            out.append(ln.text.rstrip())
    text_out = "\n".join(out) + "\n"
    return WarpResult(text_out, len(recs), len(out), len(prints), int(n.sum()),
                      float(piece_bound.max(initial=0.0)), float(safe_z))


def fixed_split_error(text: str, surface: HeightField, split_mm: float, standoff_mm: float,
                      samples_per_piece: int = 16) -> tuple[int, float]:
    """(printing pieces, worst |z error| mm) when printing moves are split every ``split_mm``
    (Klipper's bed mesh / bCNC), measured against the surface at ``samples_per_piece`` points per piece."""
    recs = [r for r in _scan(text) if r[0] == "print"]
    if not recs:
        return 0, 0.0
    p0 = np.array([r[2] for r in recs])
    p1 = np.array([r[3] for r in recs])
    length = np.hypot(p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1])
    n = np.maximum(1, np.ceil(length / split_mm)).astype(np.int64)
    seg = np.repeat(np.arange(len(recs)), n)
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
