"""Pads and areas as fill strokes, and wide traces as side-by-side passes (top view, mm).

A fill is one contour (the outline inset by half a line) and a raster (lines ``line_width``
apart inside the contour, inset by a whole line so the raster meets the contour), so the
deposited beads of width ``line_width`` cover the outline.  A trace wider than the line is
printed as ``ceil(width / line)`` parallel passes centred on the trace.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from shapely.geometry import LineString, MultiLineString, Polygon
from shapely.geometry.base import BaseGeometry

from app.geometry.tolerance import LENGTH_EPS_MM

#: round-off slack of ceil(width / line width) -> pass count (a width that is an exact
#: multiple of the line width must not gain a pass)
_PASS_COUNT_SLACK = 1e-9

__all__ = ["fill_strokes", "pass_offsets", "offset_polyline"]


def _lines_of(geom: BaseGeometry) -> list[npt.NDArray[np.float64]]:
    """The line strings (k, 2) mm of an intersection result (empty for anything else)."""
    if geom.is_empty:
        return []
    if isinstance(geom, LineString):
        return [np.asarray(geom.coords)]
    if isinstance(geom, MultiLineString) or hasattr(geom, "geoms"):
        return [np.asarray(g.coords) for g in geom.geoms if isinstance(g, LineString) and not g.is_empty]
    return []


def fill_strokes(exterior: npt.NDArray[np.float64], holes: Sequence[npt.NDArray[np.float64]] = (),
                 line_width_mm: float = 0.2,
                 angle_deg: float = 0.0) -> list[npt.NDArray[np.float64]]:
    """Strokes (each (k, 2) mm) that fill the polygon: contours first, then raster lines
    (alternating direction).  A region thinner than one line gets its centre line only."""
    w = float(line_width_mm)
    poly = Polygon(exterior, list(holes)).buffer(0)
    contour_region = poly.buffer(-w / 2, join_style="mitre")
    strokes: list[npt.NDArray[np.float64]] = []
    if contour_region.is_empty:                    # thinner than a line: one pass along its long axis
        rect = poly.minimum_rotated_rectangle
        c = np.asarray(rect.exterior.coords)[:4]
        e1, e2 = c[1] - c[0], c[2] - c[1]
        a, b = (c[0] + c[1]) / 2, (c[2] + c[3]) / 2
        if np.linalg.norm(e1) > np.linalg.norm(e2):
            a, b = (c[1] + c[2]) / 2, (c[3] + c[0]) / 2
        return [np.vstack([a, b])]
    for g in getattr(contour_region, "geoms", [contour_region]):
        strokes.append(np.asarray(g.exterior.coords))
        strokes += [np.asarray(r.coords) for r in g.interiors]
    raster_region = poly.buffer(-w, join_style="mitre")
    if raster_region.is_empty:
        return strokes
    t = np.radians(angle_deg)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    pts = np.asarray(raster_region.exterior.coords) @ rot       # into the raster frame (lines along x)
    y0, y1 = pts[:, 1].min(), pts[:, 1].max()
    x0, x1 = pts[:, 0].min() - 1.0, pts[:, 0].max() + 1.0
    count = max(1, int(np.floor((y1 - y0) / w)) + 1)
    ys = y0 + (y1 - y0 - (count - 1) * w) / 2 + w * np.arange(count)
    flip = False
    for y in ys:
        ray = LineString((np.array([[x0, y], [x1, y]]) @ rot.T).tolist())
        for seg in _lines_of(raster_region.intersection(ray)):
            if len(seg) >= 2 and np.linalg.norm(seg[-1] - seg[0]) > LENGTH_EPS_MM:
                strokes.append(seg[::-1] if flip else seg)
        flip = not flip
    return strokes


def pass_offsets(width_mm: float, line_width_mm: float) -> npt.NDArray[np.float64]:
    """Lateral offsets (n,) mm of the passes of a trace of ``width_mm`` (n = ceil(width / line))."""
    n = max(1, int(np.ceil(width_mm / line_width_mm - _PASS_COUNT_SLACK)))
    if n == 1:
        return np.zeros(1)
    pitch = (width_mm - line_width_mm) / (n - 1)
    offsets = (np.arange(n, dtype=np.float64) - (n - 1) / 2) * pitch
    return offsets


def offset_polyline(xy: npt.NDArray[np.float64], distance_mm: float) -> npt.NDArray[np.float64]:
    """The polyline (k, 2) moved sideways by ``distance_mm`` (left positive), vertex by vertex
    along the mitred normal of its neighbouring segments."""
    xy = np.asarray(xy, float)
    if distance_mm == 0.0:
        return xy.copy()
    d = np.diff(xy, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    n_seg = np.column_stack([-d[:, 1], d[:, 0]])
    n_v = np.vstack([n_seg[:1], n_seg[:-1] + n_seg[1:], n_seg[-1:]])
    n_v /= np.linalg.norm(n_v, axis=1, keepdims=True)
    cos_half = np.ones(len(xy))
    cos_half[1:-1] = np.clip((n_v[1:-1] * n_seg[1:]).sum(axis=1), 0.2, 1.0)
    return xy + distance_mm * n_v / cos_half[:, None]
