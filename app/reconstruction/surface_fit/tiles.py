"""Neighbourhood tiles of scattered (x, y) points, so that local fits stay small.

The bad-point test fits a height surface with a dense design matrix: one global fit over
k points costs O(k * k/3) memory (4 GB at a 200 x 200 grid).  Above a few thousand points
it runs per tile instead: the points are split at the median (alternating x and y, a k-d
tree's cells) until each cell holds at most ``core`` points; each cell's *neighbourhood*
is the cell plus the points within half a cell around it (``scipy.spatial.cKDTree``), at
most ``core * NEIGHBOURHOOD_FACTOR`` points, nearest to the cell's centre first.  Each
point is judged by the fit of its own cell's neighbourhood, so memory is bounded by the
tile size and time grows linearly with k.  Units: mm.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from app.geometry.tolerance import LENGTH_EPS_MM

NEIGHBOURHOOD_FACTOR = 3
MARGIN = 0.5  # of the cell's larger side, on every side


@dataclass(frozen=True)
class Tile:
    """core: (c,) indices of the points judged by this tile; neighbourhood: (n,) indices of
    the points fitted (core first, then the nearest others)."""

    core: np.ndarray
    neighbourhood: np.ndarray


def _cells(xy: np.ndarray, index: np.ndarray, core: int, axis: int) -> Iterator[np.ndarray]:
    """Median splits of ``index`` (points xy (k, 2)) until each cell has <= core points."""
    stack = [(index, axis)]
    while stack:
        cell, ax = stack.pop()
        if cell.size <= core:
            yield cell
            continue
        order = np.argsort(xy[cell, ax], kind="stable")
        half = cell.size // 2
        stack.append((cell[order[half:]], 1 - ax))
        stack.append((cell[order[:half]], 1 - ax))


def neighbourhood_tiles(xy: np.ndarray, core: int) -> list[Tile]:
    """Tiles covering every point of xy (k, 2) exactly once in their cores."""
    tree = cKDTree(xy)
    limit = core * NEIGHBOURHOOD_FACTOR
    tiles = []
    for cell in _cells(xy, np.arange(xy.shape[0]), core, 0):
        lo, hi = xy[cell].min(axis=0), xy[cell].max(axis=0)
        centre, half = (lo + hi) / 2, float(np.max(hi - lo)) / 2
        around = np.asarray(tree.query_ball_point(centre, r=half * (1 + 2 * MARGIN) + LENGTH_EPS_MM, p=np.inf),
                            dtype=int)
        others = np.setdiff1d(around, cell, assume_unique=False)
        if others.size > limit - cell.size:
            distance = np.max(np.abs(xy[others] - centre), axis=1)
            others = others[np.argsort(distance, kind="stable")[: max(limit - cell.size, 0)]]
        tiles.append(Tile(core=cell, neighbourhood=np.concatenate([cell, others])))
    return tiles
