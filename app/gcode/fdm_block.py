"""Layers of extrusion G-code written at once: their headers, their pieces' travels, retracts
and moves as numpy arrays, formatted in one pass and recorded as one block.

:func:`extrude_layers` writes exactly the bytes that the per-layer, per-piece loop of
:mod:`app.gcode.fdm` writes for the same layers (tests/gcode/test_fdm_written_moves.py holds
the two equal): per layer its ``;LAYER:n`` tag and the move to its height, then per piece a
move no longer than ``LENGTH_EPS_MM`` is skipped, one whose written X and Y
equal the last written is folded into the next (its filament goes with it), E is the running
sum of each move's length times its piece's filament per mm (a sequential sum, as the loop
adds), a retract (``-retract_mm``) and its undo (``+retract_mm``) go into that sum where
they are written.  Numbers are written at the builder's decimals from values rounded as the
text reads back (:func:`app.gcode.writer.as_written`), so the record handed to the builder
(:meth:`app.gcode.writer.ProgramBuilder.extend_block`) is what the reader reads.  Writing a
few layers at once costs their lines, not a fixed price per layer as well.
Units: mm, mm/min in the words.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt

from app.gcode.fixed_text import xye_lines
from app.gcode.writer import as_written
from app.geometry.tolerance import LENGTH_EPS_MM

if TYPE_CHECKING:
    from app.gcode.writer import ProgramBuilder
    from app.slicing.toolpath import PathPiece

NUMPY_TEXT_LINES = 4000  # a block with this many moves has their text built by numpy (xye_lines)


class ExtrudeState(NamedTuple):
    """The writer's running state between layers: absolute ``e`` (mm of filament), whether
    anything was extruded yet, the nozzle's position (2,) mm (None before the first piece)."""

    e: float
    extruded: bool
    pos: npt.NDArray[np.float64] | None


class LayerBlock(NamedTuple):
    """One layer to write: its number ``layer`` (the ``;LAYER:n`` tag), height ``z`` mm, print-ordered
    ``pieces`` (each ``points`` (n, 2) mm, all finite) and ``rates`` (filament mm per mm of
    each piece)."""

    layer: int
    z: float
    pieces: tuple[PathPiece, ...]
    rates: list[float]


class _Motion(NamedTuple):
    """The motion settings of a block: feeds mm/min, lengths mm."""

    travel_mm_min: float
    retract_mm: float
    retract_mm_min: float
    min_travel_for_retract_mm: float
    z_lift_mm: float


def extrude_layers(b: ProgramBuilder, layers: list[LayerBlock], state: ExtrudeState, travel_mm_min: float,
                   retract_mm: float, retract_mm_min: float, min_travel_for_retract_mm: float,
                   z_lift_mm: float) -> ExtrudeState:
    """Write ``layers`` in order: per layer its tag and the move to ``z + z_lift_mm`` (the
    travel feed), then per piece a retract when something was extruded and the travel is
    longer than ``min_travel_for_retract_mm``, the travel, the lift's return, the undo of the
    retract, a ``; TYPE:<kind>`` comment, then its moves with E and the feed on the first; a
    lift after it when ``z_lift_mm``.  Returns the state after the last layer."""
    if not layers:
        return state
    motion = _Motion(travel_mm_min, retract_mm, retract_mm_min, min_travel_for_retract_mm, z_lift_mm)
    pieces = tuple(p for lay in layers for p in lay.pieces)
    per_layer = np.fromiter((len(lay.pieces) for lay in layers), dtype=np.int64, count=len(layers))
    P = len(pieces)
    d = b.decimals
    if P == 0:
        _emit(b, layers, per_layer, pieces, _Written.empty(), motion)
        return state
    sizes = np.fromiter((len(p.points) for p in pieces), dtype=np.int64, count=P)
    pts = np.concatenate([p.points for p in pieces]).astype(np.float64, copy=False)
    rates = np.fromiter((r for lay in layers for r in lay.rates), dtype=np.float64, count=P)
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
    slots[inner + owner[inner] + 1] = np.where(move[inner - 1], seg[inner - 1] * rates[owner[inner]], 0.0)
    run = np.cumsum(np.concatenate([[state.e], slots]))[1:]
    _emit(b, layers, per_layer, pieces,
          _Written(R[heads], R[written], per_piece, retract, travel, as_written(run[first], d),
                   as_written(run[first + 1], d), as_written(run[written + owner[written] + 1], d)), motion)
    return ExtrudeState(float(run[-1]), state.extruded or bool(per_piece.sum()), pts[-1].copy())


class _Written(NamedTuple):
    """Per piece (P of them) its start as written ``heads`` (P, 2) mm, its written moves' ends
    ``moves`` (M, 2) mm and how many (``per_piece`` (P,)), whether it retracts and travels
    before it (P,), E after the retract and after its undo (P,) and after each move (M,)."""

    heads: npt.NDArray[np.float64]
    moves: npt.NDArray[np.float64]
    per_piece: npt.NDArray[np.int64]
    retract: npt.NDArray[np.bool_]
    travel: npt.NDArray[np.bool_]
    e_retracted: npt.NDArray[np.float64]
    e_restored: npt.NDArray[np.float64]
    e_moves: npt.NDArray[np.float64]

    @staticmethod
    def empty() -> _Written:
        none, no, count = np.zeros(0), np.zeros(0, dtype=bool), np.zeros(0, dtype=np.int64)
        return _Written(np.zeros((0, 2)), np.zeros((0, 2)), count, no, no, none, none, none)


def _scatter(text: npt.NDArray[np.object_], at: npt.NDArray[np.int64], lines: list[str]) -> None:
    """Put ``lines`` at the positions ``at`` of ``text`` (an object array of lines)."""
    if len(at):
        column = np.empty(len(lines), dtype=object)
        column[:] = lines
        text[at] = column


def _emit(b: ProgramBuilder, layers: list[LayerBlock], per_layer: npt.NDArray[np.int64],
          pieces: tuple[PathPiece, ...], w: _Written, m: _Motion) -> None:
    """The layers' lines and, per line, the axis values and feed as written (NaN: no such
    word), handed to the builder as one block.  Per layer: its tag, the move to its height,
    then per piece: [retract] [travel] [lift's return] [undo of the retract] comment, its
    moves, [lift]."""
    P, L = len(pieces), len(layers)
    spec = f".{b.decimals}f"
    tf, rf = b.feed_word(m.travel_mm_min), b.feed_word(m.retract_mm_min)
    travel_f, retract_f = float(tf[1:]), float(rf[1:])
    lift = 1 if m.z_lift_mm else 0
    z = np.array([lay.z for lay in layers])
    z_down, z_up = as_written(z, b.decimals), as_written(z + m.z_lift_mm, b.decimals)
    layer_of = np.repeat(np.arange(L), per_layer)
    feeds: dict[float, str] = {}
    piece_feed = [feeds.get(p.feed_mm_s) or feeds.setdefault(p.feed_mm_s, b.feed_word(p.feed_mm_s * 60.0))
                  for p in pieces]
    comments: dict[str, str] = {}
    piece_comment = [comments.get(p.kind) or comments.setdefault(p.kind, b.comment_text(f"TYPE:{p.kind}"))
                     for p in pieces]
    # where each line goes: a layer's two header lines, then its pieces' lines
    r, t = w.retract.astype(np.int64), w.travel.astype(np.int64)
    count = 2 * r + t + 2 * lift + 1 + w.per_piece
    ends = np.cumsum(count)
    first_piece = np.cumsum(per_layer) - per_layer
    at_head = np.concatenate([[0], ends])[first_piece] + 2 * np.arange(L)   # each layer's tag
    off = ends - count + 2 * (layer_of + 1)                                  # each piece's first line
    at_comment = off + 2 * r + t + lift
    starts = np.cumsum(w.per_piece) - w.per_piece
    owner = np.repeat(np.arange(P), w.per_piece)
    at_move = at_comment[owner] + 1 + np.arange(len(w.moves)) - starts[owner]
    rows = np.full((int(count.sum()) + 2 * L, 5), np.nan)
    rows[at_head + 1, 2], rows[at_head + 1, 4] = z_up, travel_f
    at_retract, at_travel, at_restore = off[w.retract], (off + r)[w.travel], (off + r + t + lift)[w.retract]
    rows[at_retract, 3], rows[at_retract, 4] = w.e_retracted[w.retract], retract_f
    rows[at_travel, 0], rows[at_travel, 1], rows[at_travel, 4] = w.heads[w.travel, 0], w.heads[w.travel, 1], travel_f
    if lift:
        rows[off + r + t, 2], rows[off + r + t, 4] = z_down[layer_of], travel_f
        rows[at_comment + 1 + w.per_piece, 2], rows[at_comment + 1 + w.per_piece, 4] = z_up[layer_of], travel_f
    rows[at_restore, 3], rows[at_restore, 4] = w.e_restored[w.retract], retract_f
    rows[at_move, 0], rows[at_move, 1], rows[at_move, 3] = w.moves[:, 0], w.moves[:, 1], w.e_moves
    has = np.flatnonzero(w.per_piece > 0)
    rows[at_comment[has] + 1, 4] = [float(piece_feed[p][1:]) for p in has.tolist()]
    # the text, each kind of line formatted in one pass and put in its place
    if len(w.moves) >= NUMPY_TEXT_LINES:
        moves = xye_lines(w.moves[:, 0], w.moves[:, 1], w.e_moves, b.decimals)
    else:
        moves = list(map(f"G1 X{{:{spec}}} Y{{:{spec}}} E{{:{spec}}}".format, w.moves[:, 0].tolist(),
                         w.moves[:, 1].tolist(), w.e_moves.tolist()))
    for p, k in zip(has.tolist(), starts[has].tolist()):
        moves[k] += " " + piece_feed[p]
    text = np.empty(len(rows), dtype=object)
    _scatter(text, at_head, [f";LAYER:{lay.layer}" for lay in layers])
    _scatter(text, at_head + 1, list(map(f"G1 Z{{:{spec}}} {tf}".format, z_up.tolist())))
    _scatter(text, at_retract, list(map(f"G1 E{{:{spec}}} {rf}".format, w.e_retracted[w.retract].tolist())))
    _scatter(text, at_travel, list(map(f"G1 X{{:{spec}}} Y{{:{spec}}} {tf}".format, w.heads[w.travel, 0].tolist(),
                                       w.heads[w.travel, 1].tolist())))
    if lift:
        _scatter(text, off + r + t, list(map(f"G1 Z{{:{spec}}} {tf}".format, z_down[layer_of].tolist())))
        _scatter(text, at_comment + 1 + w.per_piece, list(map(f"G1 Z{{:{spec}}} {tf}".format,
                                                               z_up[layer_of].tolist())))
    _scatter(text, at_restore, list(map(f"G1 E{{:{spec}}} {rf}".format, w.e_restored[w.retract].tolist())))
    _scatter(text, at_comment, piece_comment)
    _scatter(text, at_move, moves)
    b.extend_block(text.tolist(), rows)
