"""Copper graphics and text of a KiCad board (``gr_*`` and a footprint's ``fp_*`` items on a
copper layer), read from the s-expression tree (kiutils loses KiCad 7's stroke widths).

Filled polygons, rectangles and circles, and stroked ones (their outline widened by the
stroke), are copper areas; lines and arcs are traces of their stroke width.  Text is copper
area too: a KiCad 7+ TrueType text from the polygons KiCad stored with it (``render_cache``:
KiCad's own outline), any other from a TrueType outline font found on this machine
(:data:`FONTS`, rendered with ezdxf's font reader, fontTools) at the text's height and width,
justified and turned as KiCad places it.  KiCad's own stroke font is not available: such text
keeps KiCad's position, height and width, not its glyph shapes.  Without a font a text is
reported, not printed.  Every shape is in mm, y up (KiCad's y negated), no net ("").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import shapely
from shapely.geometry import Point, Polygon, box
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient

from app.circuits.curves import arc_three_points, line
from app.circuits.layout import Area, LayoutTrace, Source
from app.circuits.shapes import CHORD_MM, _quad_segs, rotate

__all__ = ["CopperGraphics", "copper_graphics", "FONTS", "text_outline"]

#: TrueType fonts tried, in order, for text without KiCad's stored outline
FONTS = ("DejaVuSans.ttf", "LiberationSans-Regular.ttf", "Arial.ttf", "arial.ttf")
_SHAPES = ("poly", "rect", "circle", "line", "arc")


@dataclass
class CopperGraphics:
    """What a copper layer's graphics give: ``areas``, ``traces``, and what was not read
    (``unread``: entity names, e.g. a text without a font or a KiCad 5 arc)."""

    areas: list[Area] = field(default_factory=list)
    traces: list[LayoutTrace] = field(default_factory=list)
    texts: int = 0
    shapes: int = 0
    unread: list[str] = field(default_factory=list)


def _find(item: list[Any], key: str) -> list[Any] | None:
    for sub in item[1:]:
        if isinstance(sub, list) and sub and sub[0] == key:
            return sub
    return None


def _pt(sub: list[Any] | None) -> npt.NDArray[np.float64]:
    if sub is None:
        raise ValueError("a point is missing")
    return np.array([float(sub[1]), -float(sub[2])])


def _stroke(item: list[Any]) -> float:
    """The stroke width (mm): KiCad 7+ ``(stroke (width w))``, KiCad 5/6 ``(width w)``."""
    stroke = _find(item, "stroke")
    width = _find(stroke, "width") if stroke is not None else _find(item, "width")
    return float(width[1]) if width is not None else 0.0


def _filled(item: list[Any], default: bool) -> bool:
    fill = _find(item, "fill")
    if fill is None or len(fill) < 2:
        return default
    return str(fill[1]) in ("solid", "yes")


def _layer(item: list[Any]) -> str:
    sub = _find(item, "layer")
    return str(sub[1]) if sub is not None and len(sub) > 1 else ""


def _shape(kind: str, item: list[Any]) -> BaseGeometry:
    """A filled or stroked poly / rect / circle (local mm, y up) as one area."""
    half = _stroke(item) / 2.0
    if kind == "poly":
        pts = _find(item, "pts") or []
        outline = Polygon([_pt(p) for p in pts if isinstance(p, list) and p[0] == "xy"]).buffer(0)
        filled = _filled(item, True)            # KiCad 5/6 polygons carry no fill: they are filled
    elif kind == "rect":
        (x0, y0), (x1, y1) = _pt(_find(item, "start")), _pt(_find(item, "end"))
        outline, filled = box(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)), _filled(item, False)
    else:
        c = _pt(_find(item, "center"))
        r = float(np.linalg.norm(_pt(_find(item, "end")) - c))
        outline, filled = Point(c).buffer(r, quad_segs=_quad_segs(r)), _filled(item, False)
    if filled:
        return outline.buffer(half, quad_segs=_quad_segs(half)) if half > 0 else outline
    return outline.exterior.buffer(half, quad_segs=_quad_segs(half)) if half > 0 else Polygon()


def _font(names: tuple[str, ...] = FONTS) -> str | None:
    """The first of ``names`` installed here (ezdxf's font manager), else None."""
    try:
        from ezdxf.fonts import fonts
    except ImportError:      # pragma: no cover - ezdxf is a dependency
        return None
    return next((n for n in names if fonts.font_manager.has_font(n)), None)


def _xor(rings: list[npt.NDArray[np.float64]]) -> BaseGeometry:
    """Glyph rings filled even-odd (a letter's counters are holes)."""
    shape: BaseGeometry = Polygon()
    for ring in rings:
        if len(ring) >= 3:
            shape = shape.symmetric_difference(Polygon(ring).buffer(0))
    return shape


def text_outline(text: str, height: float, width: float, font: str) -> BaseGeometry:
    """The outline of ``text`` (mm, y up) in ``font``: cap height ``height``, glyphs scaled to
    ``width`` / ``height``, baseline on y = 0 from x = 0; lines (``\\n``) 1.6 heights apart."""
    from ezdxf.fonts import fonts

    face = fonts.make_font(font, cap_height=height, width_factor=width / height if height > 0 else 1.0)
    rings = []
    for k, row in enumerate(text.split("\n")):
        for sub in face.text_path(row).sub_paths():
            pts = np.array([(v.x, v.y) for v in sub.flattening(CHORD_MM)], float)
            rings.append(pts - [0.0, 1.6 * height * k])
    return _xor(rings)


def _text(item: list[Any], font: str | None, at: npt.NDArray[np.float64], fp_angle: float) -> BaseGeometry | None:
    """A gr_text / fp_text as copper (board mm, y up), None without a font.  Its ``at`` is in
    the frame of its footprint (at ``at``, turned ``fp_angle`` rad); its angle is absolute."""
    cache = _find(item, "render_cache")
    if cache is not None:                   # KiCad's own outline of a TrueType text, board frame
        rings = [np.array([_pt(p) for p in (_find(poly, "pts") or [])[1:]]) for poly in cache[1:]
                 if isinstance(poly, list) and poly[0] == "polygon"]
        return _xor(rings)
    if font is None:
        return None
    text = str(item[2] if item[0] == "fp_text" else item[1])
    effects = _find(item, "effects") or []
    size = _find(_find(effects, "font") or [], "size")
    height, width = (float(size[1]), float(size[2])) if size is not None else (1.0, 1.0)
    shape = text_outline(text, height, width, font)
    if shape.is_empty:
        return shape
    x0, _, x1, _ = shape.bounds
    justify = [str(v) for v in (_find(effects, "justify") or [])[1:]]
    dx = -x0 if "left" in justify else -x1 if "right" in justify else -(x0 + x1) / 2
    dy = 0.0 if "bottom" in justify else -height if "top" in justify else -height / 2
    shape = shapely.affinity.translate(shape, dx, dy)
    if "mirror" in justify:
        shape = shapely.affinity.scale(shape, -1.0, 1.0, origin=(0, 0))
    local = _find(item, "at") or ["at", 0, 0]
    angle = float(local[3]) if len(local) > 3 else 0.0
    x, y = rotate(_pt(local)[None, :], fp_angle)[0] + at
    return shapely.affinity.translate(shapely.affinity.rotate(shape, angle, origin=(0, 0)), float(x), float(y))


def _areas(shape: BaseGeometry, src: Source) -> list[Area]:
    """The polygons of ``shape`` as areas (exterior CCW, holes CW)."""
    out = []
    for g in getattr(shape, "geoms", [shape]):
        if isinstance(g, Polygon) and g.area > 0:
            g = orient(g, 1.0)
            out.append(Area(np.asarray(g.exterior.coords)[:-1], tuple(np.asarray(h.coords)[:-1] for h in g.interiors),
                            src))
    return out


def _placed(shape: BaseGeometry, at: npt.NDArray[np.float64], angle_rad: float) -> BaseGeometry:
    return shapely.affinity.translate(shapely.affinity.rotate(shape, angle_rad, origin=(0, 0), use_radians=True),
                                      float(at[0]), float(at[1]))


def copper_graphics(tree: list[Any], layer: str, name: str, *, read_text: bool = True) -> CopperGraphics:
    """Every ``gr_*`` item on ``layer`` and every footprint's ``fp_*`` item on it (placed by
    the footprint's position and angle), as areas and traces (see the module)."""
    out = CopperGraphics()
    font = _font() if read_text else None
    items: list[tuple[list[Any], npt.NDArray[np.float64], float, str]] = []
    for top in tree[1:]:
        if not isinstance(top, list) or not top:
            continue
        if str(top[0]).startswith("gr_"):
            items.append((top, np.zeros(2), 0.0, ""))
        elif top[0] in ("footprint", "module"):
            fp_at = _find(top, "at") or ["at", 0, 0]
            fp_angle = float(np.radians(float(fp_at[3]))) if len(fp_at) > 3 else 0.0
            items += [(sub, _pt(fp_at), fp_angle, f"{top[1]} ") for sub in top[1:]
                      if isinstance(sub, list) and sub and str(sub[0]).startswith("fp_")]
    for k, (item, at, angle, owner) in enumerate(items):
        if _layer(item) != layer:
            continue
        kind = str(item[0])[3:]
        entity = f"{owner}{item[0]} {k}"
        src = Source(name, layer, "", 0.0, entity)
        if kind == "text":
            effects = _find(item, "effects") or []
            if "hide" in item or "hide" in effects or _find(item, "hide") or _find(effects, "hide"):
                continue
            out.texts += 1
            words = str(item[2] if item[0] == "fp_text" else item[1])
            shape = _text(item, font, at, angle)
            if shape is None:
                out.unread.append(f"{entity} ({words!r}: no outline font)")
                continue
            out.areas += _areas(shape, Source(name, layer, "", 0.0, f"{entity} ({words!r})"))
            continue
        if kind not in _SHAPES:
            continue
        out.shapes += 1
        if kind in ("line", "arc"):
            if kind == "arc" and _find(item, "mid") is None:
                out.unread.append(f"{entity} (a KiCad 5 arc)")
                continue
            start, end = _pt(_find(item, "start")), _pt(_find(item, "end"))
            pts = np.vstack([start, end] if kind == "line" else [start, _pt(_find(item, "mid")), end])
            pts = rotate(pts, angle) + at
            curve = line(pts[0], pts[1]) if kind == "line" else arc_three_points(pts[0], pts[1], pts[2])
            out.traces.append(LayoutTrace(curve, Source(name, layer, "", _stroke(item), entity)))
            continue
        out.areas += _areas(_placed(_shape(kind, item), at, angle), src)
    return out
