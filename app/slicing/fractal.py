"""Fractal fills on a square grid of pitch ``p``: plain Hilbert and the seed's improved fill.

Both place cells of side ``p`` over the region; cell centres are path vertices.

* :func:`hilbert_fill` clips the Hilbert curve of order ``ceil(log2(n))`` over the grid to
  the region; the path breaks (a jump) wherever the curve leaves the region.
* :func:`merged_fractal_fill` (the published "improved fractal"): the base cells are 2 x 2 cell
  loops (the smallest Hilbert circuits); neighbouring loops are merged pairwise (two
  facing sides removed, two connecting sides added) along the direction of least weight
  until one Hamiltonian circuit covers each connected region: Kruskal's minimum spanning
  tree over the loops with weight ``weights.along`` for merges along the layer's raster
  direction and ``weights.across`` across it (the seed's N/V/C/T terms are constant within
  a layer, so only the merge direction changes the argmin).  Cells left outside whole
  loops at the border are spliced into the circuit in pairs (a cycle edge u-v next to two
  free cells c1-c2 becomes u-c1-c2-v), so the circuit stays single: no islands.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, NamedTuple

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from annotated_types import Ge, Le
from scipy.sparse.csgraph import minimum_spanning_tree
from shapely import contains_xy
from shapely.geometry import MultiLineString, MultiPolygon

from app.geometry.tolerance import LENGTH_EPS_MM
from app.slicing.fills import region_geometry
from app.slicing.rings import Island

IntArray = npt.NDArray[np.int64]
Edges = set[tuple[int, int]]


@dataclass(frozen=True)
class MergeWeights:
    """Merge weights of the improved fractal fill (dimensionless; the bounds are the range a
    toolpath may ask for, see :meth:`ToolpathParams.validate <app.slicing.toolpath.ToolpathParams.validate>`)."""

    along: Annotated[float, Ge(0), Le(1000)] = 1.0
    across: Annotated[float, Ge(0), Le(1000)] = 2.0


def hilbert_d2xy(order: int, d: npt.ArrayLike) -> IntArray:
    """Hilbert index ``d`` (N,) -> integer cell coordinates (N, 2) on a 2^order grid."""
    d = np.asarray(d, dtype=np.int64).copy()
    x = np.zeros_like(d)
    y = np.zeros_like(d)
    s = 1
    while s < (1 << order):
        rx = 1 & (d // 2)
        ry = 1 & (d ^ rx)
        swap = ry == 0
        flip = swap & (rx == 1)
        x[flip] = s - 1 - x[flip]
        y[flip] = s - 1 - y[flip]
        x[swap], y[swap] = y[swap].copy(), x[swap].copy()
        x += s * rx
        y += s * ry
        d //= 4
        s *= 2
    return np.stack([x, y], axis=1)


class _Grid(NamedTuple):
    """A cell grid over islands: ``origin`` (2,) mm, the first cell's centre; ``n`` (2,)
    cell counts along x and y."""

    origin: npt.NDArray[np.float64]
    n: IntArray


def _grid(islands: tuple[Island, ...], pitch: float, phase: tuple[int, int] = (0, 0)) -> _Grid:
    lo = np.min([i.outer.min(axis=0) for i in islands], axis=0)
    hi = np.max([i.outer.max(axis=0) for i in islands], axis=0)
    origin = lo + pitch * (0.5 - np.asarray(phase, dtype=np.float64))
    n = np.ceil((hi - origin) / pitch).astype(np.int64) + 1
    return _Grid(origin, n)


def _centres(origin: npt.NDArray[np.float64], ij: npt.ArrayLike, pitch: float) -> npt.NDArray[np.float64]:
    """Cell indices ``ij`` (n, 2) (or one (2,)) -> cell centres in mm, same shape."""
    return origin + pitch * np.asarray(ij, dtype=np.float64)


def _inside(region: MultiPolygon, pts: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    """(n,) whether each point of ``pts`` (n, 2) mm lies inside ``region``."""
    inside: npt.NDArray[np.bool_] = contains_xy(region, pts[:, 0], pts[:, 1])  # shapely: untyped
    return inside


def simplify_collinear(path: npt.NDArray[np.float64], tol: float = LENGTH_EPS_MM) -> npt.NDArray[np.float64]:
    """Drop vertices where the polyline (n, 2) goes straight on (keeps the ends)."""
    if len(path) < 3:
        return path
    d1 = path[1:-1] - path[:-2]
    d2 = path[2:] - path[1:-1]
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    dot = np.einsum("ij,ij->i", d1, d2)
    keep = np.ones(len(path), dtype=bool)
    keep[1:-1] = (np.abs(cross) > tol) | (dot <= 0)
    return path[keep]


def hilbert_fill(islands: tuple[Island, ...], pitch: float) -> list[npt.NDArray[np.float64]]:
    """Plain Hilbert-curve fill at ``pitch`` (mm): the curve over the region's bounding
    grid clipped to the region (as the reference slicers do); polylines (n, 2) in mm."""
    if not islands:
        return []
    region = region_geometry(islands)
    origin, n = _grid(islands, pitch)
    order = max(1, int(np.ceil(np.log2(max(int(n.max()), 2)))))
    ij = hilbert_d2xy(order, np.arange(1 << (2 * order)))
    ij = ij[(ij[:, 0] < n[0]) & (ij[:, 1] < n[1])]
    pts = _centres(origin, ij, pitch)
    step = np.abs(np.diff(ij, axis=0)).sum(axis=1)
    breaks = np.nonzero(step != 1)[0] + 1          # the curve leaves the cropped grid
    lines = [simplify_collinear(p) for p in np.split(pts, breaks) if len(p) > 1]
    clipped = region.intersection(MultiLineString(lines))
    geoms = getattr(clipped, "geoms", [clipped])
    return [np.asarray(g.coords) for g in geoms
            if g.geom_type == "LineString" and g.length > LENGTH_EPS_MM]


def _cycle_edges(full: npt.NDArray[np.bool_], ny: int, weights: MergeWeights, along_x: bool) -> Edges:
    """Edges (set of (a, b) cell ids, a < b) of the merged circuits over the full 2 x 2 blocks
    ``full`` (bx, by); cell (i, j) has id ``i * ny + j``."""
    bx, by = full.shape
    edges: Edges = set()

    def cid(i: int | np.integer, j: int | np.integer) -> int:
        return int(i) * ny + int(j)

    def add(a: int, b: int) -> None:
        edges.add((a, b) if a < b else (b, a))

    def rem(a: int, b: int) -> None:
        edges.discard((a, b) if a < b else (b, a))

    blocks = np.argwhere(full)
    for bi, bj in blocks:
        c00, c10 = cid(2 * bi, 2 * bj), cid(2 * bi + 1, 2 * bj)
        c01, c11 = cid(2 * bi, 2 * bj + 1), cid(2 * bi + 1, 2 * bj + 1)
        for e0, e1 in ((c00, c10), (c10, c11), (c11, c01), (c01, c00)):
            add(e0, e1)
    bid = -np.ones(full.shape, dtype=np.int64)
    bid[full] = np.arange(len(blocks))
    rows: list[IntArray] = []
    cols: list[IntArray] = []
    vals: list[npt.NDArray[np.float64]] = []
    w_x, w_y = (weights.along, weights.across) if along_x else (weights.across, weights.along)
    for di, dj, w in ((1, 0, w_x), (0, 1, w_y)):
        pair = full[: bx - di, : by - dj] & full[di:, dj:]
        ai, aj = np.nonzero(pair)
        rows.append(bid[ai, aj])
        cols.append(bid[ai + di, aj + dj])
        vals.append(np.full(len(ai), w))
    r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    if len(blocks) > 1 and len(r):
        tree = minimum_spanning_tree(sp.coo_matrix((v, (r, c)), shape=(len(blocks),) * 2))
        tr, tc = tree.nonzero()
        for a, b in zip(tr, tc):
            (ai, aj), (bi_, bj_) = blocks[min(a, b)], blocks[max(a, b)]
            if (bi_, bj_) < (ai, aj):
                (ai, aj), (bi_, bj_) = (bi_, bj_), (ai, aj)
            if bi_ == ai + 1:       # B right of A
                rem(cid(2 * ai + 1, 2 * aj), cid(2 * ai + 1, 2 * aj + 1))
                rem(cid(2 * bi_, 2 * bj_), cid(2 * bi_, 2 * bj_ + 1))
                add(cid(2 * ai + 1, 2 * aj), cid(2 * bi_, 2 * bj_))
                add(cid(2 * ai + 1, 2 * aj + 1), cid(2 * bi_, 2 * bj_ + 1))
            else:                   # B above A
                rem(cid(2 * ai, 2 * aj + 1), cid(2 * ai + 1, 2 * aj + 1))
                rem(cid(2 * bi_, 2 * bj_), cid(2 * bi_ + 1, 2 * bj_))
                add(cid(2 * ai, 2 * aj + 1), cid(2 * bi_, 2 * bj_))
                add(cid(2 * ai + 1, 2 * aj + 1), cid(2 * bi_ + 1, 2 * bj_))
    return edges


def _splice_free_cells(edges: Edges, free: set[int], ny: int, ok: Callable[[int, int], bool]) -> None:
    """Insert pairs of free neighbouring cells into cycle edges next to them (in place)."""
    progress = True
    while progress and free:
        progress = False
        for c1 in sorted(free):
            if c1 not in free:
                continue
            i1, j1 = divmod(c1, ny)
            for di, dj in ((1, 0), (0, 1), (-1, 0), (0, -1)):
                c2 = (i1 + di) * ny + (j1 + dj)
                if c2 not in free or not ok(c1, c2):
                    continue
                for pi, pj in ((dj, di), (-dj, -di)):      # perpendicular offsets
                    u = (i1 + pi) * ny + (j1 + pj)
                    v = (i1 + di + pi) * ny + (j1 + dj + pj)
                    key = (u, v) if u < v else (v, u)
                    if key in edges and ok(u, c1) and ok(v, c2):
                        edges.discard(key)
                        for a, b in ((u, c1), (c1, c2), (c2, v)):
                            edges.add((a, b) if a < b else (b, a))
                        free.discard(c1)
                        free.discard(c2)
                        progress = True
                        break
                if c1 not in free:
                    break


def _walk_cycles(edges: Edges) -> list[list[int]]:
    adj: dict[int, list[int]] = {}
    for a, b in sorted(edges):
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    seen: set[int] = set()
    cycles: list[list[int]] = []
    for start in sorted(adj):
        if start in seen:
            continue
        cyc, prev, cur = [start], -1, start
        seen.add(start)
        while True:
            nxt = [n for n in adj[cur] if n != prev]
            nxt_node = nxt[0] if nxt else adj[cur][0]
            if nxt_node == start:
                break
            if nxt_node in seen:
                break
            cyc.append(nxt_node)
            seen.add(nxt_node)
            prev, cur = cur, nxt_node
        cycles.append(cyc)
    return cycles


def merged_fractal_fill(islands: tuple[Island, ...], pitch: float, along_x: bool = True,
                        weights: MergeWeights = MergeWeights()) -> list[npt.NDArray[np.float64]]:
    """The published improved fractal fill: one closed circuit per connected region.

    Returns closed polylines (n, 2) mm (first vertex repeated at the end).
    """
    if not islands:
        return []
    region = region_geometry(islands)
    best: tuple[int, npt.NDArray[np.float64], int, int, npt.NDArray[np.bool_], npt.NDArray[np.bool_]] | None = None
    for phase in ((0, 0), (1, 0), (0, 1), (1, 1)):
        origin, n = _grid(islands, pitch, phase)
        nx, ny = int(n[0]) + (int(n[0]) % 2), int(n[1]) + (int(n[1]) % 2)
        ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        inside = _inside(region, _centres(origin, np.stack([ii.ravel(), jj.ravel()], 1),
                                          pitch)).reshape(nx, ny)
        blk: npt.NDArray[np.bool_] = np.asarray(inside.reshape(nx // 2, 2, ny // 2, 2).all(axis=(1, 3)))
        centre = _centres(origin, np.argwhere(blk) * 2 + 0.5, pitch)
        blk[blk] = _inside(region, centre) if len(centre) else blk[blk]
        if best is None or blk.sum() > best[0]:
            best = (int(blk.sum()), origin, nx, ny, inside, blk)
    assert best is not None  # four phases were tried
    _, origin, nx, ny, inside, full = best
    edges = _cycle_edges(full, ny, weights, along_x)

    def ok(a: int, b: int) -> bool:
        pa = _centres(origin, divmod(a, ny), pitch)
        pb = _centres(origin, divmod(b, ny), pitch)
        return bool(contains_xy(region, *(0.5 * (pa + pb))))

    used = np.zeros(nx * ny, dtype=bool)
    if edges:
        used[np.array(sorted({c for e in edges for c in e}))] = True
    free = set(np.nonzero(inside.ravel() & ~used)[0].tolist())
    _splice_free_cells(edges, free, ny, ok)
    out: list[npt.NDArray[np.float64]] = []
    for cyc in _walk_cycles(edges):
        ij = np.array([divmod(c, ny) for c in cyc], dtype=float)
        pts = _centres(origin, ij, pitch)
        pts = np.vstack([pts, pts[:1]])
        closed = simplify_collinear(np.vstack([pts, pts[1:2]]))[:-1]
        closed = closed if np.allclose(closed[0], closed[-1]) else np.vstack([closed,
                                                                              closed[:1]])
        out.append(closed)
    return out
