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
from scipy.spatial import cKDTree


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
NEIGHBOURS = 8  # beyond that, each candidate's nearest others remembered


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
    if any(closed):
        cand = np.concatenate([p[:-1] if c else p[[0, -1]] for p, c in zip(remaining, closed)])
    else:
        cand = np.stack([heads, tails], axis=1).reshape(-1, 2)
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
    """The greedy order of :func:`order_paths` as (path, candidate within it) pairs, for any
    number of candidates.  Each candidate's ``NEIGHBOURS`` nearest others are found once (a
    k-d tree) with their squared distances in the search's own arithmetic, sorted by
    (distance, candidate): from a candidate, the first living one in that list is the
    nearest living candidate overall when it is nearer than the list's last (every
    candidate outside the list is at least that far).  Otherwise (no living neighbour, a
    tie with the list's end, or the nozzle not on a candidate) every living candidate is
    searched."""
    n = len(cand)
    k = min(NEIGHBOURS + 1, n)
    _, near = cKDTree(cand).query(cand, k=k)
    near = near.reshape(n, k)
    dx, dy = cand[near, 0] - cand[:, None, 0], cand[near, 1] - cand[:, None, 1]
    d2 = dx * dx + dy * dy
    order_in = np.lexsort((near, d2), axis=1)
    near, d2 = np.take_along_axis(near, order_in, axis=1), np.take_along_axis(d2, order_in, axis=1)
    near_rows, d2_rows = near.tolist(), d2.tolist()
    full = k == n                              # the list holds every candidate: no one outside it
    owner = owner_of.tolist()
    first = owner_first.tolist()
    xs, ys = cand[:, 0].tolist(), cand[:, 1].tolist()
    alive = [True] * len(closed)
    living = np.ones(len(closed), dtype=bool)  # the same, for the full search
    order: list[tuple[int, int]] = []
    at: int | None = None                      # the candidate the nozzle is on, if any
    px, py = float(pos[0]), float(pos[1])
    for _ in range(len(closed)):
        j = -1
        if at is not None:
            bound = d2_rows[at][-1]
            for c, d in zip(near_rows[at], d2_rows[at]):
                if alive[owner[c]]:
                    if full or d < bound * (1.0 - 1e-12):
                        j = c
                    break
        if j < 0:                              # every living candidate, in candidate order
            held = np.flatnonzero(living[owner_of])
            ex, ey = cand[held, 0] - px, cand[held, 1] - py
            j = int(held[np.argmin(ex * ex + ey * ey)])
        p = owner[j]
        order.append((p, j - first[p]))
        alive[p] = living[p] = False
        if closed[p] and j == first[p] and not (tails[p] == cand[j]).all():
            at, (px, py) = None, tails[p].tolist()
        else:
            at = _stop(first[p], closed[p], j)
            px, py = xs[at], ys[at]
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
