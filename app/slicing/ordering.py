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


class OrderedPaths(NamedTuple):
    """Polylines (n, 2) mm in print order and orientation, and the nozzle's final position (2,) mm."""

    paths: list[npt.NDArray[np.float64]]
    end: npt.NDArray[np.float64]


def order_paths(paths: list[npt.NDArray[np.float64]], start: npt.NDArray[np.float64]) -> OrderedPaths:
    """Order (and orient) ``paths`` (list of (n, 2) mm) starting at ``start`` (2,).

    Returns the re-ordered polylines and the final nozzle position (2,) (:class:`OrderedPaths`).
    """
    remaining = [np.asarray(p, dtype=float) for p in paths if len(p) >= 2]
    out: list[npt.NDArray[np.float64]] = []
    pos = np.asarray(start, dtype=float)
    if not remaining:
        return OrderedPaths(out, pos)
    heads = np.array([p[0] for p in remaining])
    tails = np.array([p[-1] for p in remaining])
    closed = _closed_mask(heads, tails, np.array([len(p) for p in remaining]))
    alive = np.ones(len(remaining), dtype=bool)
    loops = np.flatnonzero(closed)
    # every closed loop's vertices (the repeated last one left out), and whose they are:
    # the nearest vertex of any loop still to print is one vectorised argmin
    loop_points = np.concatenate([remaining[k][:-1] for k in loops]) if len(loops) else np.zeros((0, 2))
    loop_of = np.repeat(loops, [len(remaining[k]) - 1 for k in loops])
    loop_first = np.concatenate([[0], np.cumsum([len(remaining[k]) - 1 for k in loops])])[:-1]
    first_vertex = dict(zip(loops.tolist(), loop_first.tolist()))
    for _ in range(len(remaining)):
        dh = np.where(alive, np.hypot(*(heads - pos).T), np.inf)
        dt = np.where(alive & ~closed, np.hypot(*(tails - pos).T), np.inf)
        k_h, k_t = int(np.argmin(dh)), int(np.argmin(dt))
        best_closed, best_d, best_v = -1, np.inf, 0
        if len(loop_points):
            dl = np.where(alive[loop_of], np.hypot(*(loop_points - pos).T), np.inf)
            j = int(np.argmin(dl))
            if np.isfinite(dl[j]):
                best_closed, best_d = int(loop_of[j]), float(dl[j])
                best_v = j - first_vertex[best_closed]
        cands = [(dh[k_h], k_h, "head"), (dt[k_t], k_t, "tail"),
                 (best_d, best_closed, "loop")]
        d, k, how = min(cands, key=lambda c: (c[0], c[1]))
        p = remaining[k]
        if how == "tail":
            p = p[::-1]
        elif how == "loop":
            p = _rotate_closed(p, best_v)
        out.append(p)
        alive[k] = False
        pos = p[-1]
    return OrderedPaths(out, pos)
