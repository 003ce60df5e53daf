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
from app.slicing.rings import Island


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


def scan_intervals(islands: tuple[Island, ...], pitch: float, angle: float = 0.0) -> ScanIntervals:
    """Scan-line intersections of the region.

    Returns ``(ys, rows)`` (:class:`ScanIntervals`) in the frame rotated by ``-angle``: ``ys`` (K,) scan heights and
    ``rows[k]`` an (m, 2) array of [x_start, x_end] material intervals, sorted by x.
    """
    rot = _rotation(-angle)
    edges = []
    for isl in islands:
        for ring in isl.rings():
            r = ring @ rot.T
            edges.append(np.stack([r, np.roll(r, -1, axis=0)], axis=1))
    if not edges:
        return ScanIntervals(np.zeros(0), [])
    e = np.concatenate(edges)                                   # (E, 2, 2)
    y_lo, y_hi = e[:, :, 1].min(), e[:, :, 1].max()
    n = int(np.floor((y_hi - y_lo) / pitch))
    ys = y_lo + pitch * (0.5 + np.arange(max(n, 0) + 1))
    ys = ys[ys < y_hi]
    if len(ys) == 0:
        ys = np.array([0.5 * (y_lo + y_hi)])
    y0, y1 = e[:, 0, 1], e[:, 1, 1]
    x0, x1 = e[:, 0, 0], e[:, 1, 0]
    rows: list[npt.NDArray[np.float64]] = []
    for y in ys:
        hit = (y0 <= y) != (y1 <= y)
        t = (y - y0[hit]) / (y1[hit] - y0[hit])
        xs = np.sort(x0[hit] + t * (x1[hit] - x0[hit]))
        rows.append(xs[: len(xs) // 2 * 2].reshape(-1, 2))
    return ScanIntervals(ys, rows)


def _to_world(points: npt.NDArray[np.float64], angle: float) -> npt.NDArray[np.float64]:
    return points @ _rotation(angle).T


def _link_ok(region: BaseGeometry, a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], max_len: float) -> bool:
    if np.hypot(*(b - a)) > max_len:
        return False
    return bool(region.covers(shapely.LineString([a, b])))


def _chain(segments: list[npt.NDArray[np.float64]], region: BaseGeometry,
           max_link: float) -> list[npt.NDArray[np.float64]]:
    """Join consecutive (2, 2) world segments into polylines when the link stays inside."""
    out: list[list[npt.NDArray[np.float64]]] = []
    for seg in segments:
        if out and _link_ok(region, out[-1][-1][-1], seg[0], max_link):
            out[-1].append(seg)
        else:
            out.append([seg])
    return [np.vstack(parts) for parts in out]


def raster_fill(islands: tuple[Island, ...], pitch: float, angle: float = 0.0,
                zigzag: bool = True) -> list[npt.NDArray[np.float64]]:
    """Direct raster: row after row across the whole layer, alternating direction.

    ``zigzag`` joins a row's last segment to the next row's first one with an extruded
    link when that link is shorter than 3 pitches and inside the region; otherwise the
    nozzle jumps (the seed's "many jumps at cavities").
    """
    ys, rows = scan_intervals(islands, pitch, angle)
    segs: list[npt.NDArray[np.float64]] = []
    for k, (y, iv) in enumerate(zip(ys, rows)):
        order = iv if k % 2 == 0 else iv[::-1, ::-1]
        for x0, x1 in order:
            segs.append(_to_world(np.array([[x0, y], [x1, y]]), angle))
    if not zigzag:
        return segs
    return _chain(segs, region_geometry(islands).buffer(LENGTH_EPS_MM), 3 * pitch)


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
