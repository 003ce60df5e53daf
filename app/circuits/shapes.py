"""Pad outlines as polygons (k, 2) mm, CCW, first point not repeated."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from shapely.geometry import LineString, Polygon, box

from app.circuits.layout import circle_ring

__all__ = ["pad_outline", "rotate", "ring_of", "outline_rings"]

CHORD_MM = 0.001


def rotate(points: npt.NDArray[np.float64], angle_rad: float) -> npt.NDArray[np.float64]:
    """Points (k, 2) rotated CCW about the origin by ``angle_rad``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    turned: npt.NDArray[np.float64] = np.asarray(points, float) @ np.array([[c, s], [-s, c]])
    return turned


def ring_of(polygon: Polygon) -> npt.NDArray[np.float64]:
    """The exterior of a shapely polygon as (k, 2) CCW without the closing point."""
    from shapely.geometry.polygon import orient

    ring = np.asarray(orient(polygon, 1.0).exterior.coords)
    return ring[:-1]


def _quad_segs(radius: float) -> int:
    """Segments per quarter circle so the chord error stays below CHORD_MM."""
    if radius <= CHORD_MM:
        return 1
    step = 2.0 * np.arccos(1.0 - CHORD_MM / radius)
    return max(1, int(np.ceil((np.pi / 2) / step)))


def pad_outline(shape: str, width: float, height: float, *, corner_radius: float = 0.0) -> npt.NDArray[np.float64]:
    """Outline (k, 2) mm of a pad centred at the origin, unrotated.

    shape: ``circle`` (diameter = width), ``rect``, ``oval`` (stadium: the short side is round),
    ``roundrect`` (corner_radius); anything else is drawn as its bounding rectangle.
    """
    if shape == "circle":
        return circle_ring(np.zeros(2), width / 2.0, CHORD_MM)
    if shape == "oval":
        r = min(width, height) / 2.0
        half = max(width, height) / 2.0 - r
        axis = LineString([(-half, 0), (half, 0)] if width >= height else [(0, -half), (0, half)])
        if half <= 0:
            return circle_ring(np.zeros(2), r, CHORD_MM)
        return ring_of(axis.buffer(r, quad_segs=_quad_segs(r)))
    if shape == "roundrect" and corner_radius > 0:
        r = min(corner_radius, width / 2.0, height / 2.0)
        inner = box(-width / 2 + r, -height / 2 + r, width / 2 - r, height / 2 - r)
        return ring_of(inner.buffer(r, quad_segs=_quad_segs(r), join_style="round"))
    return ring_of(box(-width / 2, -height / 2, width / 2, height / 2))


def outline_rings(lines: list[LineString]) -> list[npt.NDArray[np.float64]]:
    """The closed rings (k, 2) mm, largest first, that a board outline's strokes enclose
    (lines, sampled arcs, closed rings; in any order, noded where they meet)."""
    import shapely

    if not lines:
        return []
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.union_all(lines))))
    polys = [g for g in faces if isinstance(g, Polygon) and g.area > 0]
    return [ring_of(g) for g in sorted(polys, key=lambda g: -g.area)]
