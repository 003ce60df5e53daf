"""KiCad pads as KiCad draws them: the outline (k, 2) mm of one pad in its own frame, y up,
unrotated (the caller turns it by the pad's angle and moves it to the pad's centre).

Shapes: ``circle``, ``oval``, ``rect``, ``roundrect`` (corner radius = ratio x the short
side), chamfered corners (``chamfer`` corners, size = chamfer ratio x the short side, on
``rect`` and ``roundrect``), ``trapezoid`` (``rect_delta``, which kiutils does not read: the
caller gives it from the s-expression) and ``custom`` (the anchor, a rect or circle of the
pad's size, united with its primitives: filled polygons, lines of their width, circles and
rectangles filled or stroked, arcs stroked).  KiCad's pad frame is y down, so a point
(x, y) there is (x, -y) here and KiCad's ``top_left`` corner is this frame's upper left.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from shapely.geometry import LineString, Point, Polygon, box
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

from app.circuits.shapes import CHORD_MM, _quad_segs, pad_outline, ring_of

__all__ = ["kicad_pad_outline", "trapezoid_corners"]


def _up(pos: Any) -> tuple[float, float]:
    return float(pos.X), -float(pos.Y)


def trapezoid_corners(width: float, height: float, delta: tuple[float, float]) -> npt.NDArray[np.float64]:
    """KiCad's trapezoid (its ``rect_delta`` (dx, dy) in its y-down frame), as (4, 2) y up, CCW:
    the side at -x is ``height + dx`` tall and the side at +x ``height - dx``; the side at -y
    (y up; KiCad's lower side) is ``width + dy`` wide and the side at +y ``width - dy``."""
    hx, hy = width / 2.0, height / 2.0
    dx, dy = delta[0] / 2.0, delta[1] / 2.0
    down = np.array([[-hx - dy, hy + dx], [hx + dy, hy - dx], [hx - dy, -hy + dx], [-hx + dy, -hy - dx]])
    up = down * [1.0, -1.0]
    return ring_of(Polygon(up))


def _chamfered(width: float, height: float, radius: float, chamfer: float, corners: list[str]) -> BaseGeometry:
    """A rectangle with the named corners cut at 45 degrees by ``chamfer`` mm and every other
    corner rounded by ``radius`` mm (as KiCad draws a chamfered round-rect)."""
    r = min(radius, width / 2.0, height / 2.0)
    c = min(chamfer, width / 2.0, height / 2.0)
    shape: BaseGeometry = box(-width / 2, -height / 2, width / 2, height / 2)
    signs = {"top_left": (-1, 1), "top_right": (1, 1), "bottom_left": (-1, -1), "bottom_right": (1, -1)}
    for name, (sx, sy) in signs.items():
        x, y = sx * width / 2, sy * height / 2
        if name in corners and c > 0:
            shape = shape.difference(Polygon([(x, y), (x - sx * c, y), (x, y - sy * c)]))
        elif r > 0:
            cx, cy = x - sx * r, y - sy * r
            corner = box(min(x, cx), min(y, cy), max(x, cx), max(y, cy))
            shape = shape.difference(corner).union(
                Point(cx, cy).buffer(r, quad_segs=_quad_segs(r)).intersection(corner))
    return shape


def _primitive(prim: Any) -> BaseGeometry:
    """One custom-pad primitive (kiutils GrPoly/GrLine/GrCircle/GrRect/GrArc) as a shapely area."""
    kind = type(prim).__name__
    half = max(float(getattr(prim, "width", 0.0) or 0.0), 0.0) / 2.0
    filled = str(getattr(prim, "fill", "") or "") in ("yes", "solid")
    if kind == "GrPoly":
        poly = Polygon([_up(p) for p in prim.coordinates]).buffer(0)
        return poly.buffer(half) if half > 0 else poly          # pad polygons are always filled
    if kind == "GrLine":
        return LineString([_up(prim.start), _up(prim.end)]).buffer(half) if half > 0 else Polygon()
    if kind == "GrCircle":
        c, e = np.array(_up(prim.center)), np.array(_up(prim.end))
        r = float(np.linalg.norm(e - c))
        disk = Point(c).buffer(r + half, quad_segs=_quad_segs(r + half))
        return disk if filled or half == 0 else disk.difference(Point(c).buffer(max(r - half, 0.0),
                                                                                 quad_segs=_quad_segs(r)))
    if kind == "GrRect":
        (x0, y0), (x1, y1) = _up(prim.start), _up(prim.end)
        rect = box(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))
        return rect.buffer(half, join_style="mitre") if filled or half == 0 else rect.exterior.buffer(half)
    if kind == "GrArc":
        from app.circuits.curves import arc_three_points

        curve = arc_three_points(np.array(_up(prim.start)), np.array(_up(prim.mid)), np.array(_up(prim.end)))
        pts = curve.evaluate(np.linspace(*curve.domain, 65))
        return LineString(pts).buffer(half) if half > 0 else Polygon()
    return Polygon()


def kicad_pad_outline(pad: Any, rect_delta: tuple[float, float] | None = None) -> npt.NDArray[np.float64]:
    """The outline (k, 2) mm of a kiutils pad in its own frame (y up, unrotated)."""
    w = float(pad.size.X)
    h = float(pad.size.Y or pad.size.X)
    shape = str(pad.shape)
    radius = float(pad.roundrectRatio or 0.0) * min(w, h) if shape == "roundrect" else 0.0
    if pad.chamfer and pad.chamferRatio and shape in ("rect", "roundrect"):
        return ring_of(_largest(_chamfered(w, h, radius, float(pad.chamferRatio) * min(w, h), list(pad.chamfer))))
    if shape == "trapezoid":
        return trapezoid_corners(w, h, rect_delta or (0.0, 0.0))
    if shape == "custom":
        anchor_kind = getattr(pad.customPadOptions, "anchor", None) or "circle"
        anchor = Polygon(pad_outline("circle" if anchor_kind == "circle" else "rect", w, h))
        union = unary_union([anchor, *(_primitive(p) for p in pad.customPadPrimitives)])
        return ring_of(_largest(union.simplify(CHORD_MM / 10)))
    return pad_outline(shape, w, h, corner_radius=radius)


def _largest(geom: BaseGeometry) -> Polygon:
    """The largest polygon of a geometry (a pad is one piece of copper)."""
    parts = [g for g in getattr(geom, "geoms", [geom]) if isinstance(g, Polygon)]
    return max(parts, key=lambda g: g.area)
