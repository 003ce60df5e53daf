"""One print program for a circuit: strokes (3-D polylines at the nozzle tip) in an order
that keeps travel short, each printed between the dispense codes, travel at a safe height.

Ordering: greedy nearest neighbour from the machine origin over the strokes' two ends (a
stroke may be printed backwards; no 2-opt), searched in a k-d tree; the result reports the
travel length against the input order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from app.gcode.writer import ProgramBuilder

__all__ = ["Stroke", "CircuitProgram", "order_strokes", "write_circuit_program"]


@dataclass(frozen=True)
class Stroke:
    """points (k, 3) mm of the nozzle tip; kind: trace / pass / pad / area; name: its source."""

    points: npt.NDArray[np.float64]
    kind: str
    name: str
    feed_mm_min: float


@dataclass(frozen=True)
class CircuitProgram:
    text: str
    order: list[tuple[int, bool]]          # (stroke index, reversed)
    travel_mm: float
    travel_input_order_mm: float
    strokes: int


def _travel(starts: npt.NDArray[np.float64], ends: npt.NDArray[np.float64]) -> float:
    return float(np.linalg.norm(starts[1:, :2] - ends[:-1, :2], axis=1).sum() + np.linalg.norm(starts[0, :2]))


def order_strokes(strokes: list[Stroke]) -> list[tuple[int, bool]]:
    """Greedy nearest-neighbour order (index, reversed) from (0, 0): each next stroke is the one
    whose head or tail is nearest to where the last one ended (a tail: printed backwards).

    The ends are searched in a k-d tree (the nearest ``k`` ends, ``k`` grown until one of a
    stroke still to print is among them), rebuilt over the ends still open once half of those
    it holds are printed: O(n log n) for a board's thousands of strokes, where a scan of every
    end per step is O(n^2)."""
    n = len(strokes)
    if n == 0:
        return []
    ends = np.vstack([np.array([s.points[0, :2] for s in strokes]),
                      np.array([s.points[-1, :2] for s in strokes])])      # (2n, 2): heads, then tails
    left = np.ones(n, bool)
    ids = np.arange(2 * n)                                                # the ends the tree holds
    tree = cKDTree(ends)
    at = np.zeros(2)
    order: list[tuple[int, bool]] = []
    for step in range(n):
        k = 8
        while True:
            k = min(k, len(ids))
            d, j = tree.query(at, k=k)
            cand = ids[np.atleast_1d(j)]
            open_ = left[cand % n]
            if open_.any():
                dist = np.atleast_1d(d)
                best = dist[open_].min()                                  # ties: a head first, then the lowest index
                tied = cand[open_ & (dist <= best)]
                pick = int(min(tied, key=lambda e: (e >= n, e % n)))
                break
            k *= 4
        i, rev = pick % n, pick >= n
        order.append((i, bool(rev)))
        left[i] = False
        at = ends[i] if rev else ends[n + i]                              # where it ends
        if 4 * (n - step - 1) < len(ids) and step + 1 < n:               # half of the tree's ends printed
            ids = np.flatnonzero(np.tile(left, 2))
            tree = cKDTree(ends[ids])
    return order


def write_circuit_program(strokes: list[Stroke], *, dialect: str, dispense_on: str, dispense_off: str,
                          clearance_mm: float, part_top_mm: float, job_id: str | None = None,
                          approach_mm: float = 0.5, plunge_feed_mm_min: float = 100.0,
                          decimals: int = 4) -> CircuitProgram:
    """The program: per stroke, travel at the safe height, plunge, dispense on, print, dispense off."""
    order = order_strokes(strokes)
    travel_z = max(part_top_mm, max(float(s.points[:, 2].max()) for s in strokes)) + clearance_mm
    b = ProgramBuilder(dialect, "circuit_program", job_id, decimals=decimals)
    b.comment(f"{len(strokes)} strokes ordered for short travel")
    b.rapid(z=travel_z)
    for index, rev in order:
        s = strokes[index]
        pts = s.points[::-1] if rev else s.points
        b.comment(f"{s.kind} {s.name}"[:120])
        x0, y0, z0 = pts[0]
        b.rapid(x=x0, y=y0).rapid(z=z0 + approach_mm)
        b.move(z=z0, feed_mm_min=plunge_feed_mm_min)
        b.raw(dispense_on.strip())
        b.extend_moves(pts[1:], s.feed_mm_min)   # the feed on the first move only
        b.raw(dispense_off.strip())
        b.rapid(z=travel_z)
    b.end()
    starts = np.array([(strokes[i].points[-1] if r else strokes[i].points[0]) for i, r in order])
    ends = np.array([(strokes[i].points[0] if r else strokes[i].points[-1]) for i, r in order])
    naive_s = np.array([s.points[0] for s in strokes])
    naive_e = np.array([s.points[-1] for s in strokes])
    return CircuitProgram(b.text(), order, _travel(starts, ends), _travel(naive_s, naive_e), len(strokes))
