"""Fill paths per layer: ``plan_toolpath(slice_result, ToolpathParams) -> Toolpath``.

Per layer: ``perimeters`` closed loops at offsets w/2, 3w/2, ... inside the section, then
the infill of the remaining region (offset n*w, or w/2 without perimeters) with the chosen
pattern at pitch ``line_width / infill`` (raster direction rotated by ``angle_step_deg``
each layer), then travel ordering.  Statistics per layer: extruded path length, travel
length, turns (direction changes above ``turn_threshold_deg`` inside extruded
polylines), jumps (travel moves between polylines) and the planner's estimated time
(:mod:`app.gcode.estimator`).  Lengths mm, times s, feeds mm/s, accelerations mm/s^2.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Annotated, Literal, NamedTuple

import numpy as np
import numpy.typing as npt
import shapely
from annotated_types import Ge, Gt, Le

from app.domain.checks import require_declared_bounds, require_positive
from app.gcode.estimator import MachineLimits, estimate_moves
from app.gcode.fdm import bead_area_mm2
from app.geometry.tolerance import DEGENERATE_LENGTH_MM, LENGTH_EPS_MM
from app.slicing.errors import SlicingError
from app.slicing.fills import contour_fill, raster_fill, zone_fill
from app.slicing.fractal import MergeWeights, hilbert_fill, merged_fractal_fill
from app.slicing.layers import SliceResult
from app.slicing.offset import offset_islands
from app.slicing.ordering import order_paths
from app.slicing.path_memo import LayerMemo, PathMemo, ShellMemo
from app.slicing.rings import Island, split_at

Pattern = Literal["raster", "lines", "contour", "zone", "hilbert", "hilbert_merged"]
RESOLUTION_MM = 0.0125  # PrusaSlicer's G-code resolution: paths simplified to it, no move shorter
THINNEST_WALL = 0.25  # of the nozzle: a wall thinner than this is not printed (PrusaSlicer's min feature)
THIN_WALL_STEPS = 10  # bisection steps finding a thin wall's half thickness (w/2 / 2^10: 0.2 um at 0.4 mm)
HEIGHT_DECIMALS = 9  # a layer's bead height in the planner's statistics and memo, to the nm
PATTERNS = ("raster", "lines", "contour", "zone", "hilbert", "hilbert_merged")


@dataclass(frozen=True)
class ToolpathParams:
    """Fill and motion parameters.

    ``pattern``: raster (zigzag), lines (raster without links), contour, zone, hilbert,
    hilbert_merged (the published improved fractal).  ``infill``: density in (0, 1].
    ``filament_mm``: filament diameter for E (extrusion mode).  ``resolution_mm``: every
    path is simplified to it (a vertex is dropped when the path moves less than this from
    the computed one) and no move is shorter (the firmware plans shorter moves uselessly).
    The bounds in the annotations are the ranges a toolpath may ask for (the toolpath job's
    parameter model reads them); :meth:`validate` refuses a value outside them.
    """

    pattern: Pattern = "raster"
    line_width_mm: Annotated[float, Gt(0), Le(20)] = 0.4
    nozzle_mm: Annotated[float, Gt(0), Le(20)] = 0.4
    layer_height_mm: Annotated[float, Gt(0), Le(20)] | None = None
    infill: Annotated[float, Gt(0), Le(1)] = 1.0
    perimeters: Annotated[int, Ge(0), Le(100)] = 1
    angle_deg: Annotated[float, Ge(-360), Le(360)] = 45.0
    angle_step_deg: Annotated[float, Ge(-360), Le(360)] = 90.0
    print_feed_mm_s: float = 40.0
    perimeter_feed_mm_s: float = 30.0
    travel_feed_mm_s: float = 120.0
    filament_mm: Annotated[float, Gt(0), Le(10)] = 1.75
    turn_threshold_deg: Annotated[float, Ge(0), Le(180)] = 10.0
    resolution_mm: Annotated[float, Ge(0.001), Le(1)] = RESOLUTION_MM
    limits: MachineLimits = field(default_factory=MachineLimits)
    merge_weights: MergeWeights = field(default_factory=MergeWeights)

    def validate(self) -> None:
        """Raise :class:`SlicingError` naming the first bad field."""
        if self.pattern not in PATTERNS:
            raise SlicingError(f"unknown fill pattern {self.pattern!r}; expected one of "
                               f"{list(PATTERNS)}", field="params.pattern", value=self.pattern)
        require_positive(self, ("print_feed_mm_s", "perimeter_feed_mm_s", "travel_feed_mm_s"),
                         SlicingError, prefix="params.")
        require_declared_bounds(self, SlicingError, prefix="params.")
        require_declared_bounds(self.merge_weights, SlicingError, prefix="params.merge_weight_")
        require_declared_bounds(self.limits, SlicingError, prefix="params.")
        self.limits.validate()


@dataclass(frozen=True, eq=False)
class PathPiece:
    """One extruded polyline: ``points`` (n, 2) mm; ``kind`` perimeter | infill | thin_wall;
    ``width_mm``: its bead width when it is not the line width (a thin wall's single bead)."""

    kind: str
    points: npt.NDArray[np.float64]
    feed_mm_s: float
    width_mm: float | None = None


@dataclass(frozen=True)
class PathCounts:
    """A layer's (or all layers') moves: extruded ``path_mm`` and ``travel_mm`` (mm), the
    ``turns`` sharper than the turn threshold and the ``jumps`` between pieces (counts)."""

    path_mm: float
    travel_mm: float
    turns: int
    jumps: int


@dataclass(frozen=True)
class LayerStats(PathCounts):
    """Per-layer (or total) statistics: the moves' :class:`PathCounts` and the planner's own
    estimate of their time, ``time_s`` (s)."""

    time_s: float


@dataclass(frozen=True, eq=False)
class LayerToolpath:
    """Print-ordered pieces of one layer at height ``z`` (mm) with ``thickness`` (mm)."""

    index: int
    z: float
    thickness: float
    pieces: tuple[PathPiece, ...]
    stats: LayerStats


@dataclass(frozen=True, eq=False)
class Toolpath:
    """All layers, the totals and the estimator description."""

    layers: tuple[LayerToolpath, ...]
    params: ToolpathParams
    totals: LayerStats
    estimator: str


def count_turns(points: npt.NDArray[np.float64], threshold_rad: float) -> int:
    """Direction changes above ``threshold_rad`` along a polyline (n, 2) (a closed one,
    first == last, also counts the closing junction)."""
    return turns_of([points], threshold_rad)


def _closed(heads: npt.NDArray[np.float64], tails: npt.NDArray[np.float64],
            sizes: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """(n,) polylines with more than two vertices whose first equals the last (within
    :func:`numpy.allclose`'s default tolerances)."""
    return (sizes > 2) & (np.abs(heads - tails) <= 1e-8 + 1e-5 * np.abs(tails)).all(axis=1)


def turns_of(paths: list[npt.NDArray[np.float64]], threshold_rad: float) -> int:
    """:func:`count_turns` summed over ``paths`` (each (n, 2) mm), all in one vectorised pass."""
    paths = [p for p in paths if len(p)]
    if not paths:
        return 0
    sizes = np.array([len(p) for p in paths])
    points = np.concatenate(paths)
    owner = np.repeat(np.arange(len(paths)), sizes)
    d = np.diff(points, axis=0)
    keep = (owner[1:] == owner[:-1]) & (np.hypot(d[:, 0], d[:, 1]) > DEGENERATE_LENGTH_MM)
    d, d_owner = d[keep], owner[1:][keep]
    # a closed path with two or more moves also turns from its last move into its first
    moves = np.bincount(d_owner, minlength=len(paths))
    ends = np.cumsum(sizes)
    closed = _closed(points[ends - sizes], points[ends - 1], sizes) & (moves > 1)
    first_move = np.cumsum(moves) - moves
    d = np.concatenate([d, d[first_move[closed]]])
    d_owner = np.concatenate([d_owner, np.flatnonzero(closed)])
    order = np.argsort(d_owner, kind="stable")
    d, d_owner = d[order], d_owner[order]
    ang = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs((np.diff(ang) + np.pi) % (2 * np.pi) - np.pi)
    return int(np.count_nonzero((turn > threshold_rad) & (d_owner[1:] == d_owner[:-1])))


def infill_paths(islands: tuple[Island, ...], params: ToolpathParams,
                 layer_index: int) -> list[npt.NDArray[np.float64]]:
    """Infill polylines of one section (unordered), pattern per ``params``."""
    w = params.line_width_mm
    region = offset_islands(islands, -(params.perimeters * w if params.perimeters else w / 2))
    if not region:
        return []
    pitch = w / params.infill
    angle = math.radians(params.angle_deg + layer_index * params.angle_step_deg)
    p = params.pattern
    if p in ("raster", "lines"):
        return raster_fill(region, pitch, angle, zigzag=(p == "raster"))
    if p == "zone":
        return zone_fill(region, pitch, angle)
    if p == "contour":
        return contour_fill(region, pitch)
    # grid fills: cell centres may sit half a line into the innermost perimeter's bead
    # (overlap), so that the cells reach the perimeter; beads still stay inside the ring
    grid_region = offset_islands(islands, -max(params.perimeters - 0.5, 0.5) * w)
    if p == "hilbert":
        return hilbert_fill(grid_region, pitch)
    return merged_fractal_fill(grid_region, pitch, along_x=(layer_index % 2 == 0),
                               weights=params.merge_weights)


def perimeter_paths(islands: tuple[Island, ...], params: ToolpathParams,
                    first: tuple[Island, ...] | None = None) -> list[npt.NDArray[np.float64]]:
    """Closed perimeter loops (first vertex repeated), outermost first.  ``first``: the
    islands already offset by half a line width inward (the outermost loops), if known."""
    out: list[npt.NDArray[np.float64]] = []
    for k in range(params.perimeters):
        loops = first if k == 0 and first is not None else offset_islands(islands, -(params.line_width_mm * (0.5 + k)))
        for isl in loops:
            out.extend(np.vstack([r, r[:1]]) for r in isl.rings())
    return out


def _drop_short(points: npt.NDArray[np.float64], shortest: float) -> npt.NDArray[np.float64]:
    """``points`` (n, 2) without the vertices that end a move shorter than ``shortest`` (mm);
    the first and last stay (the vertex before the last goes instead)."""
    while len(points) > 2:
        seg = np.hypot(*np.diff(points, axis=0).T)
        drop = np.flatnonzero(seg < shortest) + 1
        if not len(drop):
            break
        drop[drop == len(points) - 1] -= 1
        drop = np.unique(drop[drop > 0])
        drop = drop[np.concatenate([[True], np.diff(drop) > 1])]  # never two neighbours in one pass
        if not len(drop):
            break
        points = np.delete(points, drop, axis=0)
    return points


def simplify_paths(paths: list[npt.NDArray[np.float64]], resolution: float) -> list[npt.NDArray[np.float64]]:
    """Each polyline (n, 2) mm simplified to ``resolution`` mm (Douglas-Peucker in GEOS, all
    of a layer's paths in one call), then without moves shorter than ``resolution``; paths
    that are no longer than it are dropped.  A closed path stays closed."""
    paths = [p for p in paths if len(p) >= 2]
    if not paths:
        return []
    lines = shapely.linestrings(np.vstack(paths), indices=np.repeat(np.arange(len(paths)), [len(p) for p in paths]))
    coords, index = shapely.get_coordinates(shapely.simplify(lines, resolution, preserve_topology=False),
                                            return_index=True)
    seg = np.hypot(*np.diff(coords, axis=0).T)
    inside = index[1:] == index[:-1]
    short = np.zeros(len(paths), dtype=bool)
    short[index[1:][inside & (seg < resolution)]] = True
    length = np.bincount(index[1:][inside], weights=seg[inside], minlength=len(paths))
    out: list[npt.NDArray[np.float64]] = []
    for k, points in enumerate(split_at(coords, np.flatnonzero(np.diff(index)) + 1)):
        if short[k]:
            points = _drop_short(points, resolution)
            if len(points) >= 2 and np.hypot(*np.diff(points, axis=0).T).sum() >= resolution:
                out.append(points)
        elif len(points) >= 2 and length[k] >= resolution:
            out.append(points)
    return out


def _open_path(ring: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """A sliver's ring (n, 2), both sides of one line, as that line: the ring from a point
    farthest from its start to the point farthest from that one."""
    a = int(np.argmax(np.hypot(*(ring - ring[0]).T)))
    rolled = np.roll(ring, -a, axis=0)
    b = int(np.argmax(np.hypot(*(rolled - rolled[0]).T)))
    return rolled[: b + 1]


def _too_thin(islands: tuple[Island, ...], inset: tuple[Island, ...]) -> list[Island]:
    """The islands of which nothing survives the inward offset ``inset`` (every island of
    ``inset`` lies inside the island it came from: its first vertex tells which)."""
    if not inset:
        return list(islands)
    x, y = np.array([isl.outer[0] for isl in inset]).T
    return [isl for isl in islands if not shapely.contains_xy(shapely.Polygon(isl.outer, isl.holes), x, y).any()]


def thin_wall_paths(islands: tuple[Island, ...], params: ToolpathParams,
                    inset: tuple[Island, ...] | None = None) -> list[tuple[npt.NDArray[np.float64], float]]:
    """Single-bead paths for the islands too thin for a bead of the line width (no inward
    offset of w/2 survives): each one's centre line and the wall thickness there, as
    ``(points (n, 2) mm, width mm)``.  The centre is what survives the deepest inward offset
    (found by bisection); a ring-shaped wall (a tube) gives a closed loop, a sliver (a rib)
    the line along it.  Walls thinner than ``THINNEST_WALL`` of the nozzle are not printed.
    ``inset``: ``islands`` offset inward by w/2 when the caller has it (one offset for all)."""
    half = params.line_width_mm / 2
    if inset is None:
        inset = offset_islands(islands, -half)
    out: list[tuple[npt.NDArray[np.float64], float]] = []
    for island in _too_thin(islands, inset):
        alone = (island,)
        lo, hi = 0.0, half
        for _ in range(THIN_WALL_STEPS):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if offset_islands(alone, -mid) else (lo, mid)
        if 2 * lo < THINNEST_WALL * params.nozzle_mm:
            continue
        for core in offset_islands(alone, -lo):
            ring = core.outer
            path = np.vstack([ring, ring[:1]]) if core.holes else _open_path(ring)
            out.append((path, 2 * lo))
    return out


class _Moves(NamedTuple):
    """A layer as planner moves: ``positions`` (m, 4) x, y, z mm and E (mm of filament),
    ``feeds`` (m - 1,) mm/s into each position after the first, ``stops`` (m,) full stops."""

    positions: npt.NDArray[np.float64]
    feeds: npt.NDArray[np.float64]
    stops: npt.NDArray[np.bool_]


def piece_e_per_mm(piece: PathPiece, line_width_mm: float, height_mm: float, filament_area_mm2: float) -> float:
    """Filament (mm) per mm of ``piece``: its bead's cross-section (its own width, else the
    line width, at ``height_mm``) over the filament's."""
    return bead_area_mm2(piece.width_mm or line_width_mm, height_mm) / filament_area_mm2


def _layer_moves(pieces: tuple[PathPiece, ...], start: npt.NDArray[np.float64], z: float, height_mm: float,
                 params: ToolpathParams) -> _Moves:
    """Travel to each piece then along it from ``start`` (2,) mm at height ``z`` mm,
    extruding each piece's bead (:func:`piece_e_per_mm`) of ``height_mm``."""
    fil_area = math.pi * (params.filament_mm / 2) ** 2
    if not pieces:
        return _Moves(np.array([[*start, z, 0.0]]), np.zeros(0), np.array([True]))
    sizes = np.array([len(p.points) for p in pieces])
    xy = np.concatenate([start[None, :], *(p.points for p in pieces)])
    rate = np.repeat([piece_e_per_mm(p, params.line_width_mm, height_mm, fil_area) for p in pieces], sizes)
    feeds = np.repeat([p.feed_mm_s for p in pieces], sizes)
    heads = np.cumsum(sizes) - sizes                      # each piece's first point (a travel's end)
    feeds[heads] = params.travel_feed_mm_s
    step = np.hypot(*np.diff(xy, axis=0).T) * rate
    step[heads] = 0.0                                     # travels extrude nothing
    stops = np.zeros(len(xy), dtype=bool)
    stops[[0, -1]] = True
    positions = np.c_[xy, np.full(len(xy), z), np.concatenate([[0.0], np.cumsum(step)])]
    return _Moves(positions, feeds.astype(np.float64), stops)


class LayerPaths(NamedTuple):
    """One section's extrusion polylines before travel ordering, each simplified to the
    resolution: ``perimeters`` (closed, outermost first), ``walls`` (one list of polylines
    and its bead width per thin wall) and ``infill``; (n, 2) mm each."""

    perimeters: list[npt.NDArray[np.float64]]
    walls: list[tuple[list[npt.NDArray[np.float64]], float]]
    infill: list[npt.NDArray[np.float64]]


Shell = tuple[list[npt.NDArray[np.float64]], list[tuple[list[npt.NDArray[np.float64]], float]]]


def layer_shell(islands: tuple[Island, ...], params: ToolpathParams) -> Shell:
    """A section's perimeters and thin walls (:class:`LayerPaths`' first two fields): what
    does not depend on the layer's infill angle."""
    res = params.resolution_mm
    inset = offset_islands(islands, -params.line_width_mm / 2)   # the outer perimeter and the thin-wall test
    walls = [(simplify_paths([path], res), width) for path, width in thin_wall_paths(islands, params, inset)]
    return simplify_paths(perimeter_paths(islands, params, inset), res), walls


def layer_paths(islands: tuple[Island, ...], layer_index: int, params: ToolpathParams,
                shell: Shell | None = None) -> LayerPaths:
    """The unordered polylines of one section (:class:`LayerPaths`); ``shell``: its
    :func:`layer_shell` when the caller has it (the same section at another angle)."""
    perimeters, walls = layer_shell(islands, params) if shell is None else shell
    return LayerPaths(perimeters, walls, simplify_paths(infill_paths(islands, params, layer_index),
                                                        params.resolution_mm))


def layer_pieces(islands: tuple[Island, ...], layer_index: int, start: npt.NDArray[np.float64],
                 params: ToolpathParams,
                 memo: PathMemo[LayerPaths] | None = None) -> tuple[tuple[PathPiece, ...], npt.NDArray[np.float64]]:
    """One section's print-ordered pieces from ``start`` (2,) mm: perimeters, thin walls'
    single beads, infill, each simplified to ``params.resolution_mm``; and where it ends."""
    if memo is not None:
        key, normal = memo.key(islands, layer_index)
        paths = memo.lookup(key, normal, layer_index)
    else:
        paths = layer_paths(islands, layer_index, params)
    return ordered_pieces(paths, start, params)


def ordered_pieces(paths: LayerPaths, start: npt.NDArray[np.float64],
                   params: ToolpathParams) -> tuple[tuple[PathPiece, ...], npt.NDArray[np.float64]]:
    """``paths`` in print order from ``start`` (2,) mm as pieces, and where they end."""
    per, pos = order_paths(paths.perimeters, start)
    walls: list[PathPiece] = []
    for wall, width in paths.walls:  # each wall's bead has its own width
        ordered, pos = order_paths(wall, pos)
        walls.extend(PathPiece("thin_wall", q, params.perimeter_feed_mm_s, width) for q in ordered)
    inf, end = order_paths(paths.infill, pos)
    pieces = tuple([PathPiece("perimeter", p, params.perimeter_feed_mm_s) for p in per] + walls
                   + [PathPiece("infill", p, params.print_feed_mm_s) for p in inf])
    return pieces, (end if len(inf) else pos)


def _layer_stats(pieces: tuple[PathPiece, ...], pos: npt.NDArray[np.float64], z: float, h: float,
                 params: ToolpathParams, thr: float) -> LayerStats:
    """The statistics of a layer's ``pieces`` printed from ``pos`` (2,) mm at height ``z`` with
    beads ``h`` mm high (``thr``: the turn threshold, rad)."""
    positions, feeds, stops = _layer_moves(pieces, pos, z, h, params)
    hops = np.hypot(*np.diff(positions[:, :2], axis=0).T)
    sizes = np.array([len(p.points) for p in pieces], dtype=np.int64)
    heads = np.cumsum(sizes) - sizes
    is_head = np.zeros(len(hops), dtype=bool)
    is_head[heads] = True                                 # the moves onto each piece
    gaps = hops[heads[1:]]                                # from one piece's end to the next one's start
    t = estimate_moves(positions, feeds, params.limits, stops) if len(feeds) else [0.0]
    return LayerStats(path_mm=float(hops[~is_head].sum()), travel_mm=float(hops[is_head].sum()),
                      turns=turns_of([p.points for p in pieces], thr),
                      jumps=int(np.count_nonzero(gaps > LENGTH_EPS_MM)), time_s=float(np.sum(t)))


def iter_toolpath(slice_result: SliceResult, params: ToolpathParams = ToolpathParams()) -> Iterator[LayerToolpath]:
    """The layers of :func:`plan_toolpath` one at a time (a caller that writes each one out
    holds one layer's paths, never all of them)."""
    params.validate()
    thr = math.radians(params.turn_threshold_deg)
    pos = np.zeros(2)
    shells: ShellMemo[Shell] = ShellMemo(params, layer_shell)
    memo: PathMemo[LayerPaths] = PathMemo(params, lambda normal, index, p: layer_paths(normal, index, p,
                                                                                        shells.get(normal)))
    done: LayerMemo[tuple[tuple[PathPiece, ...], npt.NDArray[np.float64], LayerStats]] = LayerMemo()
    for lay in slice_result.layers:
        # the bead height to the nm: a layer's thickness is a difference of its heights, whose
        # last bits differ from layer to layer (layers.npz rounds them), the layer does not
        h = round(params.layer_height_mm or lay.thickness, HEIGHT_DECIMALS)
        key, normal = memo.key(lay.islands, lay.index)
        found = done.get(key, h, pos)
        if found is None:
            pieces, end = ordered_pieces(memo.lookup(key, normal, lay.index), pos, params)
            stats = _layer_stats(pieces, pos, lay.z_top, h, params, thr)
            done.put(key, h, pos, (pieces, end, stats))
        else:
            pieces, end, stats = found
        yield LayerToolpath(lay.index, lay.z_top, lay.thickness, pieces, stats)
        pos = end


def totals_of(stats: Iterable[LayerStats]) -> LayerStats:
    """The sum of per-layer statistics."""
    rows = list(stats)
    return LayerStats(path_mm=sum(x.path_mm for x in rows), travel_mm=sum(x.travel_mm for x in rows),
                      turns=sum(x.turns for x in rows), jumps=sum(x.jumps for x in rows),
                      time_s=sum(x.time_s for x in rows))


def plan_toolpath(slice_result: SliceResult, params: ToolpathParams = ToolpathParams()) -> Toolpath:
    """Perimeters + thin walls + infill + travel ordering + statistics for every layer."""
    layers = tuple(iter_toolpath(slice_result, params))
    return Toolpath(layers, params, totals_of(x.stats for x in layers), params.limits.describe())
