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


def _is_closed(p: npt.NDArray[np.float64]) -> bool:
    return len(p) > 2 and bool(np.allclose(p[0], p[-1]))


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
    closed = np.array([_is_closed(p) for p in remaining])
    heads = np.array([p[0] for p in remaining])
    tails = np.array([p[-1] for p in remaining])
    alive = np.ones(len(remaining), dtype=bool)
    for _ in range(len(remaining)):
        dh = np.where(alive, np.hypot(*(heads - pos).T), np.inf)
        dt = np.where(alive & ~closed, np.hypot(*(tails - pos).T), np.inf)
        # closed loops: any vertex may be the start; use the nearest one (cheap bound first)
        k_h, k_t = int(np.argmin(dh)), int(np.argmin(dt))
        best_closed, best_d, best_v = -1, np.inf, 0
        for loop in np.nonzero(alive & closed)[0]:
            d = np.hypot(*(remaining[loop][:-1] - pos).T)
            v = int(np.argmin(d))
            if d[v] < best_d:
                best_closed, best_d, best_v = int(loop), float(d[v]), v
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
