"""One layer of extrusion G-code written at once: its pieces' travels, retracts and moves as
numpy arrays, formatted in one pass and recorded as one block.

:func:`extrude_layer` writes exactly the bytes that the per-piece loop of
:mod:`app.gcode.fdm` writes for the same pieces (tests/gcode/test_fdm_written_moves.py holds
the two equal): a move no longer than ``LENGTH_EPS_MM`` is skipped, one whose written X and Y
equal the last written is folded into the next (its filament goes with it), E is the running
sum of each move's length times its piece's filament per mm (a sequential sum, as the loop
adds), a retract (``-retract_mm``) and its undo (``+retract_mm``) go into that sum where
they are written.  Numbers are written at the builder's decimals from values rounded as the
text reads back (:func:`app.gcode.writer.as_written`), so the record handed to the builder
(:meth:`app.gcode.writer.ProgramBuilder.extend_block`) is what the reader reads.
Units: mm, mm/min in the words.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt

from app.gcode.writer import as_written
from app.geometry.tolerance import LENGTH_EPS_MM

if TYPE_CHECKING:
    from app.gcode.writer import ProgramBuilder
    from app.slicing.toolpath import PathPiece

class ExtrudeState(NamedTuple):
    """The writer's running state between layers: absolute ``e`` (mm of filament), whether
    anything was extruded yet, the nozzle's position (2,) mm (None before the first piece)."""

    e: float
    extruded: bool
    pos: npt.NDArray[np.float64] | None


def extrude_layer(b: ProgramBuilder, pieces: tuple[PathPiece, ...], rates: list[float], z: float,
                  state: ExtrudeState, travel_mm_min: float, retract_mm: float, retract_mm_min: float,
                  min_travel_for_retract_mm: float, z_lift_mm: float) -> ExtrudeState:
    """Write ``pieces`` (print order; each ``points`` (n, 2) mm, all finite) at height ``z``
    mm: per piece a retract when something was extruded and the travel is longer than
    ``min_travel_for_retract_mm``, the travel, the lift's return, the undo of the retract, a
    ``; TYPE:<kind>`` comment, then its moves with E (``rates``: filament mm per mm of each
    piece) and the feed on the first; a lift after it when ``z_lift_mm``.  Returns the state
    after the layer."""
    P = len(pieces)
    if P == 0:
        return state
    d = b.decimals
    sizes = np.fromiter((len(p.points) for p in pieces), dtype=np.int64, count=P)
    pts = np.concatenate([p.points for p in pieces]).astype(np.float64, copy=False)
    N = len(pts)
    heads = np.cumsum(sizes) - sizes
    tails = heads + sizes - 1
    owner = np.repeat(np.arange(P), sizes)
    is_head = np.zeros(N, dtype=bool)
    is_head[heads] = True
    seg = np.hypot(*np.diff(pts, axis=0).T)
    move = ~is_head[1:] & (seg > LENGTH_EPS_MM)                    # move k - 1 ends at point k
    R = as_written(pts, d)
    # candidates: each piece's start and every real move's end; a move is written where its
    # end differs from the candidate before it (the last written X Y of its piece)
    cand = np.flatnonzero(is_head | np.concatenate([[False], move]))
    differs = np.ones(len(cand), dtype=bool)
    differs[1:] = (R[cand[1:]] != R[cand[:-1]]).any(axis=1)
    written = cand[differs & ~is_head[cand]]                          # point indices of the written moves
    per_piece = np.bincount(owner[written], minlength=P)
    # travels and retracts (never before anything was extruded)
    prev = np.empty((P, 2))
    prev[1:] = pts[tails[:-1]]
    prev[0] = pts[0] if state.pos is None else state.pos
    dist = np.hypot(*(pts[heads] - prev).T)
    if state.pos is None:
        dist[0] = math.inf
    extruded_before = np.concatenate([[False], np.cumsum(per_piece)[:-1] > 0]) | state.extruded
    retract = extruded_before & (dist > min_travel_for_retract_mm) & (retract_mm > 0)
    travel = dist > LENGTH_EPS_MM
    # E: one sequential running sum, in the order written: per piece "-r", "+r" (0 without a
    # retract), then its moves' filament; slot of point k (not a start): k + owner[k] + 1
    slots = np.zeros(N + P)
    first = heads + np.arange(P)
    slots[first] = np.where(retract, -retract_mm, 0.0)
    slots[first + 1] = np.where(retract, retract_mm, 0.0)
    inner = np.flatnonzero(~is_head)
    slots[inner + owner[inner] + 1] = np.where(move[inner - 1],
                                               seg[inner - 1] * np.asarray(rates, dtype=np.float64)[owner[inner]], 0.0)
    run = np.cumsum(np.concatenate([[state.e], slots]))[1:]
    _emit(b, pieces, z, R, heads, written, per_piece, retract, travel, as_written(run[first], d),
          as_written(run[first + 1], d), as_written(run[written + owner[written] + 1], d),
          travel_mm_min, retract_mm_min, z_lift_mm)
    return ExtrudeState(float(run[-1]), state.extruded or bool(per_piece.sum()), pts[-1].copy())


def _emit(b: ProgramBuilder, pieces: tuple[PathPiece, ...], z: float, R: npt.NDArray[np.float64],
          heads: npt.NDArray[np.int64], written: npt.NDArray[np.int64], per_piece: npt.NDArray[np.int64],
          retract: npt.NDArray[np.bool_], travel: npt.NDArray[np.bool_], e_retracted: npt.NDArray[np.float64],
          e_restored: npt.NDArray[np.float64], e_moves: npt.NDArray[np.float64], travel_mm_min: float,
          retract_mm_min: float, z_lift_mm: float) -> None:
    """The layer's lines and, per line, the axis values and feed as written (NaN: no such
    word), handed to the builder as one block.  Per piece: [retract] [travel] [lift's
    return] [undo of the retract] comment, its moves, [lift]."""
    P = len(pieces)
    spec = f".{b.decimals}f"
    tf, rf = b.feed_word(travel_mm_min), b.feed_word(retract_mm_min)
    lift = 1 if z_lift_mm else 0
    zd, zu = as_written(np.array([z, z + z_lift_mm]), b.decimals).tolist()
    feeds: dict[float, str] = {}
    piece_feed = [feeds.get(p.feed_mm_s) or feeds.setdefault(p.feed_mm_s, b.feed_word(p.feed_mm_s * 60.0))
                  for p in pieces]
    comments: dict[str, str] = {}
    piece_comment = [comments.get(p.kind) or comments.setdefault(p.kind, b.comment_text(f"TYPE:{p.kind}"))
                     for p in pieces]
    # where each line goes
    r, t = retract.astype(np.int64), travel.astype(np.int64)
    count = 2 * r + t + 2 * lift + 1 + per_piece
    off = np.cumsum(count) - count
    at_comment = off + 2 * r + t + lift
    starts = np.cumsum(per_piece) - per_piece
    owner = np.repeat(np.arange(P), per_piece)
    at_move = at_comment[owner] + 1 + np.arange(len(written)) - starts[owner]
    rows = np.full((int(count.sum()), 5), np.nan)
    rows[off[retract], 3], rows[off[retract], 4] = e_retracted[retract], float(rf[1:])
    k = (off + r)[travel]
    rows[k, 0], rows[k, 1], rows[k, 4] = R[heads[travel], 0], R[heads[travel], 1], float(tf[1:])
    if lift:
        rows[off + r + t, 2], rows[off + r + t, 4] = zd, float(tf[1:])
        rows[at_comment + 1 + per_piece, 2], rows[at_comment + 1 + per_piece, 4] = zu, float(tf[1:])
    k = (off + r + t + lift)[retract]
    rows[k, 3], rows[k, 4] = e_restored[retract], float(rf[1:])
    rows[at_move, 0], rows[at_move, 1], rows[at_move, 3] = R[written, 0], R[written, 1], e_moves
    has = per_piece > 0
    rows[at_comment[has] + 1, 4] = [float(piece_feed[p][1:]) for p in np.flatnonzero(has).tolist()]
    # the text
    move_lines = list(map(f"G1 X{{:{spec}}} Y{{:{spec}}} E{{:{spec}}}".format, R[written, 0].tolist(),
                          R[written, 1].tolist(), e_moves.tolist()))
    hx, hy = R[heads, 0].tolist(), R[heads, 1].tolist()
    er, es = e_retracted.tolist(), e_restored.tolist()
    zdown, zup = f"G1 Z{zd:{spec}} {tf}", f"G1 Z{zu:{spec}} {tf}"
    lines: list[str] = []
    add = lines.append
    ends = (starts + per_piece).tolist()
    for p, (rp, tp, start, end) in enumerate(zip(retract.tolist(), travel.tolist(), starts.tolist(), ends)):
        if rp:
            add(f"G1 E{er[p]:{spec}} {rf}")
        if tp:
            add(f"G1 X{hx[p]:{spec}} Y{hy[p]:{spec}} {tf}")
        if lift:
            add(zdown)
        if rp:
            add(f"G1 E{es[p]:{spec}} {rf}")
        add(piece_comment[p])
        if end > start:
            add(move_lines[start] + " " + piece_feed[p])
            lines.extend(move_lines[start + 1:end])
        if lift:
            add(zup)
    b.extend_block(lines, rows)
