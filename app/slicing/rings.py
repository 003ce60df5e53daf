"""Closed rings of one cross-section: outer boundaries (CCW) and holes (CW), nested.

Array conventions: a ring is a ``(n, 2)`` float64 array of XY vertices in mm, implicitly
closed (the last vertex is *not* repeated).  Signed area (shoelace) is positive for
anticlockwise rings, so an island's area is ``area(outer) + sum(area(hole))`` with the
hole areas negative.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import numpy.typing as npt

T = TypeVar("T")


def per_array(fn: Callable[[npt.NDArray[np.float64]], T]) -> Callable[[npt.NDArray[np.float64]], T]:
    """``fn`` computed once per ring array: the layers of a prismatic band share their section's
    ring arrays (:meth:`app.slicing.mesh_prep.PreparedMesh.prism_band`), so what works layer by
    layer (a length, an export's bytes, a move) works on each array once.  Keyed by identity
    and holding each array, so a key never names another array while the function lives."""
    done: dict[int, tuple[npt.NDArray[np.float64], T]] = {}

    def once(ring: npt.NDArray[np.float64]) -> T:
        hit = done.get(id(ring))
        if hit is None:
            hit = done[id(ring)] = (ring, fn(ring))
        return hit[1]
    return once


def following(ring: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Each vertex's successor around the closed ``ring`` (n, ...): ``np.roll(ring, -1, axis=0)``
    (the same array, without ``np.roll``'s generic set-up: ~10x faster on a short ring)."""
    return np.concatenate((ring[1:], ring[:1]))


def preceding(ring: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Each vertex's predecessor around the closed ``ring`` (n, ...): ``np.roll(ring, 1, axis=0)``."""
    return np.concatenate((ring[-1:], ring[:-1]))


def signed_area(ring: npt.NDArray[np.float64]) -> float:
    """Shoelace signed area of a closed ring ``(n, 2)`` in mm^2 (CCW positive)."""
    x = ring[:, 0]
    y = ring[:, 1]
    if len(ring) < 3:
        return 0.0
    return 0.5 * float(x[:-1] @ y[1:] - x[1:] @ y[:-1] + x[-1] * y[0] - x[0] * y[-1])


def oriented(ring: npt.NDArray[np.float64], ccw: bool) -> npt.NDArray[np.float64]:
    """``ring`` reversed if needed so that it runs anticlockwise (``ccw``) or clockwise."""
    a = signed_area(ring)
    if (a > 0) != ccw and a != 0.0:
        return ring[::-1].copy()
    return ring


@dataclass(frozen=True, eq=False)
class Island:
    """One connected region of a section: an outer ring (CCW) with its holes (CW).

    ``outer``: (n, 2) mm; ``holes``: tuple of (m, 2) mm.
    """

    outer: npt.NDArray[np.float64]
    holes: tuple[npt.NDArray[np.float64], ...] = ()

    @property
    def outer_area(self) -> float:
        """Area enclosed by the outer ring, mm^2 (positive)."""
        return signed_area(self.outer)

    @property
    def hole_areas(self) -> tuple[float, ...]:
        """Absolute areas of the holes, mm^2."""
        return tuple(-signed_area(h) for h in self.holes)

    @property
    def area(self) -> float:
        """Net material area (outer minus holes), mm^2."""
        return self.outer_area - sum(self.hole_areas)

    def rings(self) -> tuple[npt.NDArray[np.float64], ...]:
        """Outer ring first, then the holes."""
        return (self.outer, *self.holes)


@dataclass(frozen=True)
class SectionStats:
    """Ring statistics of one section (the multi-cavity slicing quantities).

    ``outer_area`` = sum A_out, ``inner_area`` = sum A_in (mm^2), ``area`` = net area,
    ``sigma`` = sum(A_in) / A_out, ``mean_inner_ratio`` = sigma / n (0 when n = 0).
    """

    area: float
    outer_area: float
    inner_area: float
    ring_count: int
    inner_ring_count: int
    sigma: float
    mean_inner_ratio: float


def section_stats(islands: tuple[Island, ...]) -> SectionStats:
    """S4 ring statistics of a section made of ``islands``."""
    a_out = float(sum(i.outer_area for i in islands))
    hole_areas = [a for i in islands for a in i.hole_areas]
    a_in = float(sum(hole_areas))
    n_in = len(hole_areas)
    sigma = a_in / a_out if a_out > 0 else 0.0
    mu = sigma / n_in if n_in else 0.0
    return SectionStats(area=a_out - a_in, outer_area=a_out, inner_area=a_in,
                        ring_count=len(islands) + n_in, inner_ring_count=n_in,
                        sigma=sigma, mean_inner_ratio=mu)


def islands_from_polygons(polygons: list[npt.NDArray[np.float64]]) -> tuple[Island, ...]:
    """Group rings (any orientation, non-crossing, even-odd nesting) into islands.

    A ring at even nesting depth is an outer boundary, at odd depth a hole of the
    smallest enclosing outer.  Output rings are re-oriented (outer CCW, holes CW).
    Islands are sorted by (min y, min x) of their outer ring for determinism.
    """
    from shapely import contains_xy
    from shapely.geometry import Polygon

    rings = [np.asarray(p, dtype=np.float64) for p in polygons if len(p) >= 3]
    rings = [r for r in rings if abs(signed_area(r)) > 0.0]
    if not rings:
        return ()
    areas = np.array([abs(signed_area(r)) for r in rings])
    order = np.argsort(-areas)
    shapes = [Polygon(rings[i]) for i in order]
    depth = np.zeros(len(order), dtype=int)
    parent = np.full(len(order), -1)
    for k in range(1, len(order)):
        probe = rings[order[k]][0]
        for j in range(k - 1, -1, -1):
            if contains_xy(shapes[j], probe[0], probe[1]):
                depth[k] = depth[j] + 1
                parent[k] = j
                break
    outers: dict[int, list[npt.NDArray[np.float64]]] = {}
    for k in range(len(order)):
        if depth[k] % 2 == 0:
            outers[k] = []
    for k in range(len(order)):
        if depth[k] % 2 == 1:
            outers[int(parent[k])].append(oriented(rings[order[k]], ccw=False))
    islands = [Island(oriented(rings[order[k]], ccw=True), tuple(holes))
               for k, holes in outers.items()]
    islands.sort(key=lambda i: (float(i.outer[:, 1].min()), float(i.outer[:, 0].min())))
    return tuple(islands)


def ring_length(ring: npt.NDArray[np.float64]) -> float:
    """Perimeter of a closed ring (n, 2) mm (the closing edge included), mm."""
    return float(np.hypot(*(following(ring) - ring).T).sum())


def split_at(values: npt.NDArray[np.float64], cuts: npt.NDArray[np.int64]) -> list[npt.NDArray[np.float64]]:
    """``numpy.split(values, cuts)`` for ascending ``cuts`` within ``len(values)``: the views
    ``values[0:c0], values[c0:c1], ..., values[ck:]``, without numpy's per-piece overhead."""
    bounds = [0, *np.asarray(cuts).tolist(), len(values)]
    return [values[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
