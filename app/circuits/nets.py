"""The printed copper against the netlist: which nets a print would join (a short).

Every printed item (a trace with its width, a pad, an area fill with its holes) is a shapely
geometry in the top view (mm) with its net ("" when the file names none).  Two items are
*joined* when they touch, or when they come closer than ``clearance_mm`` (0: touching only).
A short is

* two joined items of different named nets, or
* a chain of joined unnamed items (a pour or trace without a net) that joins items of two
  different named nets: the unnamed copper bridges them.

Each short names both nets, both items and a point (mm, top view) where they meet.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import shapely
from shapely import STRtree
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

from app.domain.errors import InvalidInput

__all__ = ["Copper", "Short", "NetShortError", "find_shorts", "check_nets", "area_polygon", "trace_copper"]


@dataclass(frozen=True)
class Copper:
    """One printed item: ``kind`` (trace, pad, area), ``name`` (its label), ``net`` ("" = unknown)
    and ``shape`` (a shapely polygon or multipolygon, top view, mm)."""

    kind: str
    name: str
    net: str
    shape: BaseGeometry

    @property
    def label(self) -> str:
        return self.name if self.name.startswith(self.kind) else f"{self.kind} {self.name}"


@dataclass(frozen=True)
class Short:
    """Two named nets the copper would join: ``items`` the two named items, ``via`` the unnamed
    item that bridges them (None when they touch directly), ``at_mm`` a point where they meet."""

    nets: tuple[str, str]
    items: tuple[str, str]
    via: str | None
    at_mm: tuple[float, float]

    def describe(self) -> str:
        a, b = self.items
        x, y = self.at_mm
        if self.via is None:
            return f"{a} (net {self.nets[0]}) touches {b} (net {self.nets[1]}) at ({x:.3f}, {y:.3f}) mm"
        return (f"{self.via} (no net) joins {a} (net {self.nets[0]}) and {b} (net {self.nets[1]}), "
                f"at ({x:.3f}, {y:.3f}) mm")

    def to_dict(self) -> dict[str, object]:
        return {"nets": list(self.nets), "items": list(self.items), "via": self.via,
                "at_mm": [round(self.at_mm[0], 6), round(self.at_mm[1], 6)]}


class NetShortError(InvalidInput):
    """A print that would short two nets; ``value``: the first short (nets, items, via, at_mm)
    and how many pairs of nets are shorted (``net_pairs``)."""


def area_polygon(exterior: npt.ArrayLike, holes: Sequence[npt.ArrayLike] = ()) -> BaseGeometry:
    """The copper of an area: exterior (k, 2) mm minus its holes (each (m, 2) mm), made valid."""
    rings = [np.asarray(h, float) for h in holes]
    poly = Polygon(np.asarray(exterior, float), [h for h in rings if len(h) >= 3])
    return poly if poly.is_valid else shapely.make_valid(poly)


def trace_copper(xy: npt.ArrayLike, width_mm: float) -> BaseGeometry:
    """The copper of a trace: its centre line (k, 2) mm widened to ``width_mm`` (round ends)."""
    pts = np.asarray(xy, float)[:, :2]
    half = max(float(width_mm), 0.0) / 2.0
    if len(pts) < 2:
        return Point(pts[0]).buffer(half)
    return LineString(pts).buffer(half) if half > 0 else LineString(pts)


def _meeting_point(a: BaseGeometry, b: BaseGeometry) -> tuple[float, float]:
    """A point (mm) where two shapes meet (on their overlap, else the nearer of the closest pair)."""
    both = a.intersection(b)
    if not both.is_empty:
        p = both.representative_point()
    else:
        p = shapely.shortest_line(a, b).interpolate(0.5, normalized=True)
    return float(p.x), float(p.y)


def _joined_pairs(shapes: Sequence[BaseGeometry], clearance_mm: float) -> np.ndarray:
    """Pairs (m, 2) i < j of shapes that touch or lie within ``clearance_mm``."""
    if len(shapes) < 2:
        return np.zeros((0, 2), int)
    geoms = np.asarray(shapes, dtype=object)
    tree = STRtree(geoms)
    if clearance_mm > 0:
        i, j = tree.query(geoms, predicate="dwithin", distance=clearance_mm)
    else:
        i, j = tree.query(geoms, predicate="intersects")
    keep = i < j
    return np.column_stack([i[keep], j[keep]])


def _root(parent: list[int], k: int) -> int:
    while parent[k] != k:
        parent[k] = parent[parent[k]]
        k = parent[k]
    return k


def find_shorts(copper: Sequence[Copper], clearance_mm: float = 0.0) -> list[Short]:
    """Every pair of named nets the copper joins (one short per pair of nets, the first found)."""
    pairs = _joined_pairs([c.shape for c in copper], clearance_mm)
    found: dict[frozenset[str], Short] = {}

    def add(nets: tuple[str, str], items: tuple[int, int], via: int | None, at: tuple[float, float]) -> None:
        key = frozenset(nets)
        if key not in found:
            found[key] = Short(nets, (copper[items[0]].label, copper[items[1]].label),
                               copper[via].label if via is not None else None, at)

    parent = list(range(len(copper)))
    touching: list[tuple[int, int]] = []          # (unnamed item, named item)
    for i, j in pairs.tolist():
        ni, nj = copper[i].net, copper[j].net
        if ni and nj:
            if ni != nj:
                add((ni, nj), (i, j), None, _meeting_point(copper[i].shape, copper[j].shape))
        elif not ni and not nj:
            parent[_root(parent, i)] = _root(parent, j)
        else:
            touching.append((i, j) if not ni else (j, i))
    first_by_group: dict[int, dict[str, tuple[int, int]]] = {}
    for unnamed, named in touching:
        nets = first_by_group.setdefault(_root(parent, unnamed), {})
        net = copper[named].net
        if net not in nets:
            nets[net] = (unnamed, named)
    for nets in first_by_group.values():
        names = list(nets)
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                (via_a, item_a), (_, item_b) = nets[names[a]], nets[names[b]]
                add((names[a], names[b]), (item_a, item_b), via_a,
                    _meeting_point(copper[via_a].shape, copper[item_a].shape))
    return list(found.values())


def check_nets(copper: Sequence[Copper], clearance_mm: float = 0.0, *, field: str = "import_id") -> int:
    """Raise :class:`NetShortError` naming the nets, the items and where, when the copper
    shorts two nets; else the number of named nets checked."""
    shorts = find_shorts(copper, clearance_mm)
    if shorts:
        more = f" (and {len(shorts) - 1} more pair(s) of nets)" if len(shorts) > 1 else ""
        raise NetShortError(f"the print would short nets {shorts[0].nets[0]} and {shorts[0].nets[1]}: "
                            f"{shorts[0].describe()}{more}", field=field,
                            value={**shorts[0].to_dict(), "net_pairs": len(shorts)})
    return len({c.net for c in copper if c.net})
