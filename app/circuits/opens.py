"""The printed copper against the source board's connections: which nets a print would open.

The source board's connections are read from the file as drawn (:func:`source_connections`):
every named net's copper (traces at their width, pads, areas with their holes, via lands and
the copper the import drops: zero-length tracks, slivers) split into its connected pieces.
A print *opens* a net when the printed items of one such piece (traces at the width they
print, pad and area fills as their beads cover them) no longer form one connected piece: a
dropped dot or sliver that joined two tracks, a pour neck narrower than the nozzle's line,
a pad off the part.  Copper closer than :data:`~app.circuits.layout.RESOLUTION_MM` counts as
joined.  Each open names the net, the two items nearest across the gap, the gap (mm) and
its middle (mm, top view).  Nets unnamed in the file ("") are not checked.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import shapely
from shapely import STRtree
from shapely.geometry import Point, Polygon
from shapely.geometry.base import BaseGeometry

from app.circuits.layout import RESOLUTION_MM, Connection, Layout
from app.circuits.nets import Copper, area_polygon, trace_copper
from app.domain.errors import InvalidInput

__all__ = ["Open", "NetOpenError", "net_pieces", "source_connections", "find_opens", "check_opens",
           "fill_coverage", "curve_points"]

#: copper closer than this (mm) is joined: the machine's resolution (with float slack)
JOIN_MM = RESOLUTION_MM * (1 + 1e-6)


@dataclass(frozen=True)
class Open:
    """A net the print splits: ``items`` the two items nearest across the gap, ``gap_mm`` the
    shortest distance between the split pieces and ``at_mm`` the gap's middle (top view)."""

    net: str
    items: tuple[str, str]
    gap_mm: float
    at_mm: tuple[float, float]

    def describe(self) -> str:
        x, y = self.at_mm
        return (f"net {self.net} is split: {self.items[0]} and {self.items[1]} are {self.gap_mm:.4f} mm apart "
                f"at ({x:.3f}, {y:.3f}) mm, where the source board connects them")

    def to_dict(self) -> dict[str, object]:
        return {"net": self.net, "items": list(self.items), "gap_mm": round(self.gap_mm, 6),
                "at_mm": [round(self.at_mm[0], 6), round(self.at_mm[1], 6)]}


class NetOpenError(InvalidInput):
    """A print that would open a net; ``value``: the first open (net, items, gap_mm, at_mm) and
    how many nets are split (``nets_open``)."""


def curve_points(curve: Any, chord_mm: float = 0.01) -> npt.NDArray[np.float64]:
    """The centre line (k, 2) mm of a layout curve: a polyline's own vertices, else samples
    dense enough for its largest curvature (sagitta <= ``chord_mm``, twice over for uneven
    parameter speed; at most 4,096)."""
    if curve.degree == 1:
        return np.asarray(curve.control_points, float)[:, :2]
    u0, u1 = (float(v) for v in curve.domain)
    kappa = float(np.nanmax(curve.curvature(np.linspace(u0, u1, 33)), initial=0.0))
    n = int(np.clip(2 * np.ceil(curve.length * np.sqrt(kappa / (8 * chord_mm))), 8, 4096)) + 1
    pts: npt.NDArray[np.float64] = np.asarray(curve.evaluate(np.linspace(u0, u1, n)), np.float64)
    return pts[:, :2]


def _union_find(n: int, pairs: npt.NDArray[np.int_]) -> npt.NDArray[np.int_]:
    """The piece label (n,) of each of n items joined by ``pairs`` (m, 2)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if n == 0:
        return np.zeros(0, int)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else \
        coo_matrix((n, n))
    labels: npt.NDArray[np.int_] = connected_components(graph, directed=False)[1]
    return labels


def _same_net_pairs(copper: Sequence[Copper]) -> npt.NDArray[np.int_]:
    """Pairs (m, 2) of items of one named net that touch (within :data:`JOIN_MM`)."""
    if len(copper) < 2:
        return np.zeros((0, 2), int)
    geoms = np.asarray([c.shape for c in copper], dtype=object)
    i, j = STRtree(geoms).query(geoms, predicate="dwithin", distance=JOIN_MM)
    nets = np.asarray([c.net for c in copper], dtype=object)
    keep = (i < j) & (nets[i] != "") & (nets[i] == nets[j])
    return np.column_stack([i[keep], j[keep]]).astype(int)


def net_pieces(copper: Sequence[Copper]) -> list[list[int]]:
    """The connected pieces (indices into ``copper``) of every named net's items."""
    labels = _union_find(len(copper), _same_net_pairs(copper))
    pieces: dict[int, list[int]] = {}
    for k, c in enumerate(copper):
        if c.net:
            pieces.setdefault(int(labels[k]), []).append(k)
    return list(pieces.values())


def source_connections(layout: Layout) -> list[Connection]:
    """The named nets' connected pieces as the file draws them (with its dropped copper and
    via lands), as indices into the layout's traces, pads and areas (pieces of >= 2 items)."""
    copper: list[Copper] = [Copper("trace", t.source.entity, t.source.net,
                                   trace_copper(curve_points(t.curve), t.width_mm)) for t in layout.traces]
    copper += [Copper("pad", p.name, p.source.net, area_polygon(p.exterior)) for p in layout.pads]
    copper += [Copper("area", a.source.entity, a.source.net, area_polygon(a.exterior, a.holes)) for a in layout.areas]
    copper += [Copper("dropped", d.source.entity, d.source.net, trace_copper(d.points, d.source.width_mm))
               for d in layout.dropped]
    copper += [Copper("via", f"via {k}", v.net, Point(v.center).buffer(v.diameter_mm / 2))
               for k, v in enumerate(layout.vias) if v.diameter_mm > 0]
    n_t, n_p, n_a = len(layout.traces), len(layout.pads), len(layout.areas)
    out = []
    for piece in net_pieces(copper):
        kept = [k for k in piece if k < n_t + n_p + n_a]
        if len(kept) < 2:
            continue
        out.append(Connection(copper[piece[0]].net, tuple(k for k in kept if k < n_t),
                              tuple(k - n_t for k in kept if n_t <= k < n_t + n_p),
                              tuple(k - n_t - n_p for k in kept if k >= n_t + n_p)))
    return out


def fill_coverage(exterior: npt.ArrayLike, holes: Sequence[npt.ArrayLike], line_width_mm: float) -> BaseGeometry:
    """The top view (mm) a pad or area fill of ``line_width_mm`` beads covers: the outline less
    every neck narrower than one line (the contour and raster run inside the outline inset by
    half a line), or, for a region thinner than a line, the bead along its long axis (as
    :func:`app.circuits.fills.fill_strokes` prints it)."""
    poly = area_polygon(exterior, holes)
    half = float(line_width_mm) / 2.0
    inner = poly.buffer(-half, join_style="mitre")
    if not inner.is_empty:
        return inner.buffer(half)
    rect = poly.minimum_rotated_rectangle
    if not isinstance(rect, Polygon):
        return poly.buffer(half)
    c = np.asarray(rect.exterior.coords)[:4]
    a, b = (c[0] + c[1]) / 2, (c[2] + c[3]) / 2
    if np.linalg.norm(c[1] - c[0]) > np.linalg.norm(c[2] - c[1]):
        a, b = (c[1] + c[2]) / 2, (c[3] + c[0]) / 2
    return trace_copper(np.vstack([a, b]), line_width_mm)


def _parts(copper: Sequence[Copper]) -> tuple[list[Copper], npt.NDArray[np.int_]]:
    """Every item split into its separate polygons (a fill a narrow neck cuts in two is two
    pieces of copper), each labelled by its item, and the item (index) of each part."""
    parts: list[Copper] = []
    owner: list[int] = []
    for k, c in enumerate(copper):
        geoms = [g for g in getattr(c.shape, "geoms", [c.shape]) if not g.is_empty] or [c.shape]
        for n, g in enumerate(geoms):
            name = c.name if len(geoms) == 1 else f"{c.label} (piece {n + 1} of {len(geoms)})"
            parts.append(Copper(c.kind, name, c.net, g))
            owner.append(k)
    return parts, np.asarray(owner, int)


def find_opens(copper: Sequence[Copper], connections: Sequence[Sequence[int]]) -> list[Open]:
    """Every source piece (indices into ``copper``: the printed items of one net the source
    connects; items not printed left out) whose printed copper falls apart; one per net."""
    parts, owner = _parts(copper)
    labels = _union_find(len(parts), _same_net_pairs(parts))
    of_item: dict[int, list[int]] = {}
    for p, k in enumerate(owner.tolist()):
        of_item.setdefault(k, []).append(p)
    found: dict[str, Open] = {}
    for piece in connections:
        members = [p for k in piece for p in of_item.get(k, [])]
        groups: dict[int, list[int]] = {}
        for p in members:
            groups.setdefault(int(labels[p]), []).append(p)
        if len(groups) < 2 or parts[members[0]].net in found:
            continue
        ranked = sorted(groups.values(), key=len, reverse=True)
        main = shapely.union_all([parts[p].shape for p in ranked[0]])
        others = [p for group in ranked[1:] for p in group]
        d, k = min((float(main.distance(parts[p].shape)), p) for p in others)
        near = min(ranked[0], key=lambda m: float(parts[m].shape.distance(parts[k].shape)))
        mid = shapely.shortest_line(parts[near].shape, parts[k].shape).interpolate(0.5, normalized=True)
        found[parts[k].net] = Open(parts[k].net, (parts[near].label, parts[k].label), d, (float(mid.x), float(mid.y)))
    return list(found.values())


def check_opens(copper: Sequence[Copper], connections: Sequence[Sequence[int]], *, field: str = "import_id") -> int:
    """Raise :class:`NetOpenError` naming the net, the items and the gap when the printed
    copper splits a piece the source connects; else the number of pieces checked."""
    opens = find_opens(copper, connections)
    if opens:
        more = f" (and {len(opens) - 1} more net(s) split)" if len(opens) > 1 else ""
        raise NetOpenError(f"the print would open net {opens[0].net}: {opens[0].describe()}{more}", field=field,
                           value={**opens[0].to_dict(), "nets_open": len(opens)})
    return len(connections)
