"""Line-based fills of one region: raster (direct / zigzag), zone scanning, contour offset.

A region is a tuple of :class:`~app.slicing.rings.Island`.  Fills return extrusion
polylines: lists of ``(n, 2)`` float arrays in mm, in print order for their own pattern
(travel ordering between polylines is done by :mod:`app.slicing.ordering`).  Scan lines
run at ``angle`` (rad) with spacing ``pitch`` (mm) starting half a pitch inside the
region's extent, so a 100 % fill of pitch = line width covers the region edge to edge.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from app.geometry.tolerance import LENGTH_EPS_MM
from app.slicing.offset import offset_islands
from app.slicing.rings import Island, split_at


def region_geometry(islands: tuple[Island, ...]) -> MultiPolygon:
    """Shapely geometry of ``islands`` (for containment tests)."""
    return MultiPolygon([Polygon(i.outer, list(i.holes)) for i in islands])


def _rotation(angle: float) -> npt.NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


class ScanIntervals(NamedTuple):
    """Scan lines of a region in the frame rotated by ``-angle``: ``ys`` (K,) scan heights
    (mm) and ``rows[k]`` the (m, 2) [x_start, x_end] material intervals (mm) on line k."""

    ys: npt.NDArray[np.float64]
    rows: list[npt.NDArray[np.float64]]


class FlatIntervals(NamedTuple):
    """Every material interval of a region's scan lines at once, sorted by line then x:
    ``ys`` (K,) scan heights (mm, rotated frame), ``row`` (m,) the line of each interval,
    ``x0``, ``x1`` (m,) its start and end (mm, ``x0 <= x1``)."""

    ys: npt.NDArray[np.float64]
    row: npt.NDArray[np.int64]
    x0: npt.NDArray[np.float64]
    x1: npt.NDArray[np.float64]


def flat_intervals(islands: tuple[Island, ...], pitch: float, angle: float = 0.0) -> FlatIntervals:
    """The scan-line intersections of the region (:class:`FlatIntervals`), vectorised over
    edges: each edge crosses the lines whose height is in ``[min y, max y)`` of the edge."""
    rot = _rotation(-angle)
    rings = [ring for isl in islands for ring in isl.rings()]
    if not rings:
        empty = np.zeros(0)
        return FlatIntervals(empty, np.zeros(0, dtype=np.int64), empty, empty)
    a = np.concatenate(rings) @ rot.T                                    # (E, 2) edge starts
    b = np.concatenate([np.roll(r, -1, axis=0) for r in rings]) @ rot.T  # (E, 2) edge ends
    y_lo, y_hi = float(min(a[:, 1].min(), b[:, 1].min())), float(max(a[:, 1].max(), b[:, 1].max()))
    n = int(np.floor((y_hi - y_lo) / pitch))
    ys = y_lo + pitch * (0.5 + np.arange(max(n, 0) + 1))
    ys = ys[ys < y_hi]
    if len(ys) == 0:
        ys = np.array([0.5 * (y_lo + y_hi)])
    y0, y1, x0, x1 = a[:, 1], b[:, 1], a[:, 0], b[:, 0]
    first = np.searchsorted(ys, np.minimum(y0, y1), side="left")
    last = np.searchsorted(ys, np.maximum(y0, y1), side="left")   # lines first..last-1 cross the edge
    count = last - first
    edge = np.repeat(np.arange(len(a)), count)
    row = np.repeat(first, count) + np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    t = (ys[row] - y0[edge]) / (y1[edge] - y0[edge])
    xs = x0[edge] + t * (x1[edge] - x0[edge])
    order = np.lexsort((xs, row))
    row, xs = row[order], xs[order]
    # pair the crossings of each line (an odd one out, from a degenerate touch, is dropped)
    per_line = np.bincount(row, minlength=len(ys))
    starts = np.cumsum(per_line) - per_line
    rank = np.arange(len(row)) - starts[row]
    keep = rank < (per_line // 2 * 2)[row]
    row, xs = row[keep], xs[keep]
    return FlatIntervals(ys.astype(np.float64), row[0::2].astype(np.int64), xs[0::2], xs[1::2])


def scan_intervals(islands: tuple[Island, ...], pitch: float, angle: float = 0.0) -> ScanIntervals:
    """Scan-line intersections of the region.

    Returns ``(ys, rows)`` (:class:`ScanIntervals`) in the frame rotated by ``-angle``: ``ys`` (K,) scan heights and
    ``rows[k]`` an (m, 2) array of [x_start, x_end] material intervals, sorted by x.
    """
    flat = flat_intervals(islands, pitch, angle)
    if len(flat.ys) == 0:
        return ScanIntervals(flat.ys, [])
    bounds = np.searchsorted(flat.row, np.arange(1, len(flat.ys)))
    pairs = np.c_[flat.x0, flat.x1]
    return ScanIntervals(flat.ys, split_at(pairs, bounds))


def _to_world(points: npt.NDArray[np.float64], angle: float) -> npt.NDArray[np.float64]:
    return points @ _rotation(angle).T


def _links_ok(region: BaseGeometry, ends: npt.NDArray[np.float64], starts: npt.NDArray[np.float64],
              max_len: float) -> npt.NDArray[np.bool_]:
    """(m,) whether each link ``ends[i] -> starts[i]`` ((m, 2) mm) is at most ``max_len`` mm
    long and inside ``region`` (all links tested in one vectorised GEOS call)."""
    ok: npt.NDArray[np.bool_] = np.hypot(*(starts - ends).T) <= max_len
    if ok.any():
        shapely.prepare(region)
        links = shapely.linestrings(np.stack([ends[ok], starts[ok]], axis=1))
        ok[ok] = shapely.covers(region, links)
    return ok


def _chain_segments(segs: npt.NDArray[np.float64], region: BaseGeometry,
                    max_link: float) -> list[npt.NDArray[np.float64]]:
    """Join consecutive world segments ((m, 2, 2) mm) into polylines where the link from
    one's end to the next one's start is short and stays inside ``region``."""
    if len(segs) == 0:
        return []
    ok = _links_ok(region, segs[:-1, 1], segs[1:, 0], max_link)
    points = segs.reshape(-1, 2)
    return split_at(points, 2 * (np.flatnonzero(~ok) + 1))


def _chain(segments: list[npt.NDArray[np.float64]], region: BaseGeometry,
           max_link: float) -> list[npt.NDArray[np.float64]]:
    """Join consecutive (2, 2) world segments into polylines when the link stays inside."""
    if not segments:
        return []
    return _chain_segments(np.stack(segments), region, max_link)


def raster_fill(islands: tuple[Island, ...], pitch: float, angle: float = 0.0,
                zigzag: bool = True) -> list[npt.NDArray[np.float64]]:
    """Direct raster: row after row across the whole layer, alternating direction.

    ``zigzag`` joins a row's last segment to the next row's first one with an extruded
    link when that link is shorter than 3 pitches and inside the region; otherwise the
    nozzle jumps (the seed's "many jumps at cavities").
    """
    flat = flat_intervals(islands, pitch, angle)
    if len(flat.row) == 0:
        return []
    odd = (flat.row % 2).astype(bool)                       # odd lines run backwards
    order = np.lexsort((np.where(odd, -flat.x0, flat.x0), flat.row))
    odd, x0, x1, y = odd[order], flat.x0[order], flat.x1[order], flat.ys[flat.row[order]]
    begin, end = np.where(odd, x1, x0), np.where(odd, x0, x1)
    local = np.stack([np.c_[begin, y], np.c_[end, y]], axis=1)          # (m, 2, 2)
    segs = local @ _rotation(angle).T
    if not zigzag:
        return list(segs)
    return _chain_segments(segs, region_geometry(islands).buffer(LENGTH_EPS_MM), 3 * pitch)


def zone_fill(islands: tuple[Island, ...], pitch: float, angle: float = 0.0) -> list[npt.NDArray[np.float64]]:
    """Partition (zone) scanning: split the scan intervals into monotone zones (a new zone
    starts wherever the interval structure splits or merges), zigzag each zone."""
    ys, rows = scan_intervals(islands, pitch, angle)
    zones: list[list[tuple[float, float, float]]] = []
    prev_zone: list[int] = []
    for k, (y, iv) in enumerate(zip(ys, rows)):
        cur_zone: list[int] = []
        prev_iv = rows[k - 1] if k else np.zeros((0, 2))
        for a, b in iv:
            over = np.nonzero((prev_iv[:, 0] < b) & (prev_iv[:, 1] > a))[0]
            zid = -1
            if len(over) == 1:
                pa, pb = prev_iv[over[0]]
                back = np.count_nonzero((iv[:, 0] < pb) & (iv[:, 1] > pa))
                if back == 1:
                    zid = prev_zone[over[0]]
            if zid < 0:
                zones.append([])
                zid = len(zones) - 1
            zones[zid].append((y, a, b))
            cur_zone.append(zid)
        prev_zone = cur_zone
    region = region_geometry(islands).buffer(LENGTH_EPS_MM)
    out: list[npt.NDArray[np.float64]] = []
    for zone in zones:
        segs: list[npt.NDArray[np.float64]] = []
        for j, (y, a, b) in enumerate(zone):
            xs = (a, b) if j % 2 == 0 else (b, a)
            segs.append(_to_world(np.array([[xs[0], y], [xs[1], y]]), angle))
        out.extend(_chain(segs, region, 3 * pitch))
    return out


def contour_fill(islands: tuple[Island, ...], pitch: float, max_rings: int = 100_000) -> list[npt.NDArray[np.float64]]:
    """Contour-offset fill: rings at -pitch/2, -3 pitch/2, ... until the region vanishes.

    Returns closed polylines (first vertex repeated at the end), outermost first.
    """
    out: list[npt.NDArray[np.float64]] = []
    current = offset_islands(islands, -0.5 * pitch)
    while current and len(out) < max_rings:
        for isl in current:
            for ring in isl.rings():
                out.append(np.vstack([ring, ring[:1]]))
        current = offset_islands(current, -pitch)
    return out
