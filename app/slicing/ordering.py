"""Travel ordering: chain extrusion polylines so that the nozzle jumps as little as possible.

Greedy nearest-neighbour from the current nozzle position: an open polyline may be printed
in either direction; a closed polyline (first vertex == last) may start at any vertex (it
is rotated).  Then 2-opt-style reversal is not attempted: the greedy chain is within a few
per cent of optimal for fill polylines that already come in scan order.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt


def _closed_mask(heads: npt.NDArray[np.float64], tails: npt.NDArray[np.float64],
                 sizes: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """(n,) which polylines are closed (more than two vertices, first == last within
    :func:`numpy.allclose`'s default tolerances), all at once."""
    near = np.abs(heads - tails) <= 1e-8 + 1e-5 * np.abs(tails)
    return (sizes > 2) & near.all(axis=1)


def _rotate_closed(p: npt.NDArray[np.float64], k: int) -> npt.NDArray[np.float64]:
    body = p[:-1]
    body = np.roll(body, -k, axis=0)
    return np.vstack([body, body[:1]])


MATRIX_CANDIDATES = 1024  # up to this many places to start, the distances between all of them at once (8 MB)


class OrderedPaths(NamedTuple):
    """Polylines (n, 2) mm in print order and orientation, and the nozzle's final position (2,) mm."""

    paths: list[npt.NDArray[np.float64]]
    end: npt.NDArray[np.float64]


def order_paths(paths: list[npt.NDArray[np.float64]], start: npt.NDArray[np.float64]) -> OrderedPaths:
    """Order (and orient) ``paths`` (list of (n, 2) mm) starting at ``start`` (2,).

    Every place a path may start is one candidate point: an open path's first and last
    vertex, a closed path's every vertex but the repeated last, grouped by path in order;
    each step takes the nearest living candidate (by squared distance; ties: the lowest
    path, its first vertex before its last; a closed path starting at its first vertex is
    printed as it is) and retires that path's candidates (the living ones are compacted
    whenever half of those held have retired).  Returns the re-ordered polylines and the final nozzle
    position (2,) (:class:`OrderedPaths`).
    """
    remaining = [np.asarray(p, dtype=float) for p in paths if len(p) >= 2]
    out: list[npt.NDArray[np.float64]] = []
    pos = np.asarray(start, dtype=float)
    if not remaining:
        return OrderedPaths(out, pos)
    sizes = np.array([len(p) for p in remaining])
    heads = np.array([p[0] for p in remaining])
    tails = np.array([p[-1] for p in remaining])
    closed = _closed_mask(heads, tails, sizes).tolist()
    # candidates per path: open -> [first, last]; closed -> its vertices but the last
    counts = [n - 1 if c else 2 for n, c in zip(sizes.tolist(), closed)]
    cand = np.concatenate([p[:-1] if c else p[[0, -1]] for p, c in zip(remaining, closed)])
    owner_first = np.concatenate([[0], np.cumsum(counts)])
    owner_of = np.repeat(np.arange(len(remaining)), counts)
    if len(cand) <= MATRIX_CANDIDATES:
        order = _greedy_by_matrix(cand, owner_first, owner_of, closed, tails, pos)
    else:
        order = _greedy(cand, owner_first, owner_of, closed, tails, pos)
    for k, v in order:
        p = remaining[k]
        if closed[k]:
            if v:
                p = _rotate_closed(p, v)
        elif v:
            p = p[::-1]
        out.append(p)
    return OrderedPaths(out, out[-1][-1])




def _stop(first: int, closed: bool, j: int) -> int:
    """The candidate where the nozzle stops after a path whose candidates start at ``first``,
    entered at candidate ``j``: an open path's other end; a closed path's entry (it comes back
    there; printed from its first vertex, it stops at its last, equal within the closing
    tolerance: the caller takes that vertex itself)."""
    return j if closed else 2 * first + 1 - j


def _greedy(cand: npt.NDArray[np.float64], owner_first: npt.NDArray[np.int64], owner_of: npt.NDArray[np.int64],
            closed: list[bool], tails: npt.NDArray[np.float64], pos: npt.NDArray[np.float64]) -> list[tuple[int, int]]:
    """The greedy order of :func:`order_paths` as (path, candidate within it) pairs, the
    distances from the nozzle computed afresh at each step (any number of candidates)."""
    index = np.arange(len(cand))              # the candidates still held (compacted as paths retire)
    cx, cy = cand[:, 0].copy(), cand[:, 1].copy()
    retired = 0
    px, py = float(pos[0]), float(pos[1])
    order: list[tuple[int, int]] = []
    first = owner_first.tolist()
    for _ in range(len(closed)):
        dx, dy = cx - px, cy - py
        j = int(index[np.argmin(dx * dx + dy * dy)])
        k = int(owner_of[j])
        order.append((k, j - first[k]))
        lo, hi = np.searchsorted(index, [first[k], first[k + 1]])
        cx[lo:hi] = np.inf
        retired += hi - lo
        if 2 * retired > len(index):          # keep only the living candidates
            keep = np.isfinite(cx)
            index, cx, cy, retired = index[keep], cx[keep], cy[keep], 0
        px, py = (tails[k] if closed[k] and j == first[k] else cand[_stop(first[k], closed[k], j)]).tolist()
    return order


def _greedy_by_matrix(cand: npt.NDArray[np.float64], owner_first: npt.NDArray[np.int64],
                      owner_of: npt.NDArray[np.int64], closed: list[bool], tails: npt.NDArray[np.float64],
                      pos: npt.NDArray[np.float64]) -> list[tuple[int, int]]:
    """:func:`_greedy` with every candidate's squared distance to every other computed at
    once ((c, c) for c candidates, the same arithmetic): a step is one argmin of a row.
    Retired candidates are pushed to infinity, so ties still go to the lowest candidate."""

    def row_from(point: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        dx, dy = cand[:, 0] - float(point[0]), cand[:, 1] - float(point[1])
        return dx * dx + dy * dy

    row = row_from(pos)
    dx, dy = cand[None, :, 0] - cand[:, None, 0], cand[None, :, 1] - cand[:, None, 1]
    dist = dx * dx + dy * dy
    del dx, dy
    dead = np.zeros(len(cand))
    order: list[tuple[int, int]] = []
    first = owner_first.tolist()
    for _ in range(len(closed)):
        j = int(np.argmin(row + dead))
        k = int(owner_of[j])
        order.append((k, j - first[k]))
        dead[first[k]:first[k + 1]] = np.inf
        if closed[k] and j == first[k] and not (tails[k] == cand[j]).all():
            row = row_from(tails[k])
        else:
            row = dist[_stop(first[k], closed[k], j)]
    return order
