"""SVG drawings (svgelements): every stroked shape and path becomes a trace.

Transforms (nested groups), the viewBox and the document's units (mm, cm, in, pt, px at
96 per inch) are honoured by svgelements; coordinates come out in CSS px and are converted
exactly (25.4 / 96 mm per px).  SVG's y axis points down; the layout's y is up with its
origin at the page's lower-left corner: y = page height - y_svg (the page height is the
document's height, or the viewBox's when no height is given).
Segments are exact: lines (degree 1), quadratic and cubic Béziers (degree 2 and 3) and
elliptical arcs (a rational quadratic circle mapped by the ellipse's affine frame).
A path's subpaths are separate traces; a trace's width is its stroke width when set.
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterable, Iterator

import numpy as np
from svgelements import SVG, Arc, Close, CubicBezier, Group, Line, Move, Path, QuadraticBezier, Shape, Use

from app.circuits.curves import arc_ccw, concatenated, line, transformed
from app.circuits.errors import CircuitFileError
from app.circuits.layout import Layout, LayoutTrace, Source
from app.geometry.nurbs import NurbsCurve
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = ["read_svg", "PX_MM"]

PX_MM = 25.4 / 96.0


def _bezier(points: list[list[float]]) -> NurbsCurve:
    """The Bezier curve of control points (p + 1, 2) as a NURBS of degree p on [0, 1]."""
    p = len(points) - 1
    return NurbsCurve(p, np.array([0.0] * (p + 1) + [1.0] * (p + 1)), np.array(points, float), None)


def _elliptic_arc(seg: Arc) -> NurbsCurve:
    """An SVG elliptical arc exactly: the unit circle's arc under the ellipse's affine frame."""
    c = np.array([seg.center.x, seg.center.y])
    frame = np.column_stack([[seg.prx.x - c[0], seg.prx.y - c[1]], [seg.pry.x - c[0], seg.pry.y - c[1]]])
    inv = np.linalg.inv(frame)
    t0 = np.arctan2(*(inv @ (np.array([seg.start.x, seg.start.y]) - c))[::-1])
    t1 = np.arctan2(*(inv @ (np.array([seg.end.x, seg.end.y]) - c))[::-1])
    ccw = (t1 - t0) % (2 * np.pi) or 2 * np.pi
    mid = seg.point(0.5)
    best: tuple[float, float] | None = None
    for sweep in (ccw, ccw - 2 * np.pi):
        tm = t0 + sweep / 2
        err = float(np.linalg.norm(c + frame @ [np.cos(tm), np.sin(tm)] - [mid.x, mid.y]))
        if best is None or err < best[0]:
            best = (err, sweep)
    assert best is not None  # two sweeps tried
    return transformed(arc_ccw(np.zeros(2), 1.0, t0, best[1]), frame, c)


def _segment(seg: object) -> NurbsCurve | None:
    """One path segment (svgelements, px) as an exact curve; None for a move or a zero-length piece."""
    if isinstance(seg, (Line, Close)):
        a, b = np.array([seg.start.x, seg.start.y]), np.array([seg.end.x, seg.end.y])
        return line(a, b) if np.linalg.norm(b - a) > LENGTH_EPS_MM else None
    if isinstance(seg, CubicBezier):
        return _bezier([[q.x, q.y] for q in (seg.start, seg.control1, seg.control2, seg.end)])
    if isinstance(seg, QuadraticBezier):
        return _bezier([[q.x, q.y] for q in (seg.start, seg.control, seg.end)])
    if isinstance(seg, Arc):
        if np.hypot(seg.end.x - seg.start.x, seg.end.y - seg.start.y) <= LENGTH_EPS_MM and seg.sweep == 0:
            return None
        return _elliptic_arc(seg)
    return None


_UNIT_MM = {"mm": 1.0, "cm": 10.0, "in": 25.4, "pt": 25.4 / 72, "pc": 25.4 / 6, "px": PX_MM, "": PX_MM}
_LENGTH = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-z]*)\s*$")


def _mm_per_px(svg: SVG) -> float:
    """mm per svgelements px: exact from the root's width and unit (svgelements rounds the
    mm/px factor to 7 digits, 0.5 um per 100 mm), else 25.4 / 96."""
    raw = str(svg.values.get("width", "") or "")
    m = _LENGTH.match(raw)
    if m and m.group(2) in _UNIT_MM and svg.width:
        return float(m.group(1)) * _UNIT_MM[m.group(2)] / float(svg.width)
    return PX_MM


def _to_layout_frame(curve: NurbsCurve, page_height_px: float, mm_px: float) -> NurbsCurve:
    """px, y down -> mm, y up from the page's bottom edge (exact affine map)."""
    return transformed(curve, np.diag([mm_px, -mm_px]), np.array([0.0, page_height_px * mm_px]))


def _shapes(node: Iterable[object], groups: tuple[str, ...] = ()) -> Iterator[tuple[Shape, set[str]]]:
    """(shape, names of it and its enclosing groups and uses) depth first."""
    for child in node:
        if isinstance(child, Shape):
            yield child, set(groups) | _group_names(child)
        elif isinstance(child, (Group, Use)):  # a <use> holds its copy of what it refers to
            yield from _shapes(child, groups + tuple(_group_names(child)))


def read_svg(data: bytes, name: str, layers: list[str] | None = None) -> Layout:
    """Traces of an SVG file in mm (y up).  ``layers`` selects groups/elements by id or
    inkscape label (an element belongs to every enclosing group's id)."""
    try:
        svg = SVG.parse(io.BytesIO(data), reify=True, ppi=96.0)
    except Exception as exc:   # xml.etree ParseError (with line and column) and others
        pos = getattr(exc, "position", None)
        where = f"line {pos[0]}, column {pos[1]}" if pos else None
        raise CircuitFileError(f"not a readable SVG: {exc}", file=name, where=where) from exc
    height = svg.height if svg.height else (svg.viewbox.height if svg.viewbox is not None else 0.0)
    out = Layout(file=name, format="svg", units="px (96 per inch)")
    seen_layers: set[str] = set()
    mm_px = _mm_per_px(svg)
    for k, (e, groups) in enumerate(_shapes(svg)):
        seen_layers.update(groups)
        if layers and not (set(layers) & groups):
            continue
        layer = next((g for g in groups if not layers or g in layers), "")
        sw = e.values.get("stroke-width") if hasattr(e, "values") else None
        width = float(e.stroke_width) * mm_px if sw is not None and e.stroke_width else 0.0
        entity = f"<{e.values.get('tag', type(e).__name__.lower())}> {e.id or '#' + str(k)}"
        pieces: list[NurbsCurve] = []
        sub = 0
        for seg in Path(e).segments():
            if isinstance(seg, Move):
                if pieces:
                    out.traces.append(LayoutTrace(_to_layout_frame(concatenated(pieces), height, mm_px),
                                                  Source(name, layer, "", width, f"{entity} subpath {sub}")))
                    sub += 1
                pieces = []
                continue
            curve = _segment(seg)
            if curve is not None:
                pieces.append(curve)
        if pieces:
            out.traces.append(LayoutTrace(_to_layout_frame(concatenated(pieces), height, mm_px),
                                          Source(name, layer, "", width, f"{entity} subpath {sub}")))
    out.layers = tuple(sorted(seen_layers))
    if layers:
        missing = [lay for lay in layers if lay not in seen_layers]
        if missing:
            raise CircuitFileError(f"no group or element {missing[0]!r} (the file has: "
                                   f"{', '.join(sorted(seen_layers)) or 'none'})", file=name,
                                   where=f"layer {missing[0]}", field="layers")
    return out


def _group_names(e: Shape | Group | Use) -> set[str]:
    """The id and inkscape label of an element."""
    names: set[str] = set()
    if getattr(e, "id", None):
        names.add(str(e.id))
    for key in ("inkscape:label", "{http://www.inkscape.org/namespaces/inkscape}label"):
        label = e.values.get(key) if hasattr(e, "values") else None
        if label:
            names.add(str(label))
    return names
