"""Gerber RS-274X and Excellon drill files (gerbonara).

Gerber: draws (D01 lines and arcs) become traces whose width is their aperture's width;
flashes (D03) become pads with the aperture's outline (circles, rectangles, obrounds,
polygons and macros, via gerbonara's primitives); regions (G36/G37) become areas.
Excellon: every hit becomes a round pad of its tool's diameter; routed slots become traces.
Coordinates are converted to mm (an inch file's 25.4 mm per inch exactly); the y axis is up.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np
import numpy.typing as npt
from gerbonara import ExcellonFile, GerberFile
from gerbonara import graphic_objects as go
from gerbonara import graphic_primitives as gp
from gerbonara.rs274x import GerberParser
from gerbonara.utils import MM
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import unary_union

from app.circuits.curves import arc_center, line
from app.circuits.errors import CircuitFileError
from app.circuits.layout import Area, Layout, LayoutTrace, Pad, Source, Via, arc_points
from app.circuits.shapes import CHORD_MM, outline_rings, ring_of, rotate
from app.geometry.nurbs import NurbsCurve
from app.geometry.tolerance import LENGTH_EPS_MM

#: floor (rad) added to a circle's chord angle so that its segment count stays finite
_MIN_CHORD_ANGLE_RAD = 1e-12

__all__ = ["read_gerber", "read_excellon", "NOT_PRINTED"]

#: X2 aperture functions of objects that are not conductors (graphics, copper text, the board
#: profile): never printed; everything else (Conductor, the pads, no attribute at all) is
NOT_PRINTED = frozenset({"NonConductor", "Profile", "Material", "Other"})

_WHERE = re.compile(r'^.*?:(\d+)\s+"(.*?)":\s*(.*)$', re.S)
_Parsed = TypeVar("_Parsed")  # what a gerbonara loader returns (GerberFile, ExcellonFile): untyped library
_ArcCentre = tuple[bool, tuple[float, float]] | None  # gerbonara's (clockwise, centre) per outline segment
_SHAPES = {"CircleAperture": "circle", "RectangleAperture": "rect", "ObroundAperture": "oval",
           "PolygonAperture": "polygon", "ExcellonTool": "circle"}


def _parse(loader: Callable[..., _Parsed], text: str, name: str) -> _Parsed:
    """Run a gerbonara parser; its SyntaxErrors name the line; a missing end marker is a truncation."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            parsed = loader(text, filename=name)
        except SyntaxError as exc:
            m = _WHERE.match(str(exc))     # gerbonara: 'name:LINE "statement": message'
            line_no = exc.lineno or (int(m.group(1)) if m else None)
            message = f'{m.group(3)} (statement "{m.group(2)}")' if m else str(exc)
            raise CircuitFileError(message, file=name, where=f"line {line_no}" if line_no else None) from exc
        except Exception as exc:  # gerbonara raises ValueError/KeyError/... on damaged files
            raise CircuitFileError(f"cannot read the file: {exc}", file=name) from exc
    for w in caught:
        text_w = str(w.message)
        if "missing mandatory M02" in text_w or "truncated" in text_w.lower():
            last = len(text.splitlines())
            raise CircuitFileError("the file ends without its end marker (M02 / M30): truncated", file=name,
                                   where=f"line {last}")
    return parsed


class _RegionAttributeParser(GerberParser):  # type: ignore[misc]
    """gerbonara's parser, but each region (G36 ... G37) keeps the object attributes (%TO%, e.g.
    the X2 net ``.N``) and the aperture attributes (%TA%, e.g. ``.AperFunction``) in effect at
    its end, as lines and flashes keep theirs."""

    def _parse_region_start(self, match: re.Match[str]) -> None:
        self._region_first = len(self.target.objects)
        super()._parse_region_start(match)

    def _parse_region_end(self, match: re.Match[str]) -> None:
        super()._parse_region_end(match)
        for obj in self.target.objects[getattr(self, "_region_first", len(self.target.objects)):]:
            if isinstance(obj, go.Region):
                obj.attrs = {**self.aperture_attrs, **self.graphics_state.object_attrs}


def _load_gerber(text: str, filename: str) -> GerberFile:
    """A Gerber file parsed with region attributes kept (see :class:`_RegionAttributeParser`)."""
    gerber = GerberFile()
    _RegionAttributeParser(gerber).parse(text, filename=filename)
    return gerber


def _primitive_geometry(prim: gp.GraphicPrimitive) -> Polygon:
    """A gerbonara primitive (mm) as a shapely polygon (empty for what has no area)."""
    if isinstance(prim, gp.Circle):
        r = prim.r
        return Point(prim.x, prim.y).buffer(r, quad_segs=max(8, int(np.ceil(np.pi / 2 / (2 * np.arccos(
            max(0.0, 1 - CHORD_MM / r)) + _MIN_CHORD_ANGLE_RAD))))) if r > 0 else Polygon()
    if isinstance(prim, gp.Rectangle):
        corners = np.array([[-prim.w, -prim.h], [prim.w, -prim.h], [prim.w, prim.h], [-prim.w, prim.h]]) / 2
        return Polygon(rotate(corners, prim.rotation) + [prim.x, prim.y])
    if isinstance(prim, gp.Line):
        return LineString([(prim.x1, prim.y1), (prim.x2, prim.y2)]).buffer(prim.width / 2)
    if isinstance(prim, gp.ArcPoly):
        return Polygon(_outline_points(prim.outline, prim.arc_centers))
    return Polygon()


def _outline_points(outline: Sequence[tuple[float, float]],
                    arc_centers: Sequence[_ArcCentre] | None) -> npt.NDArray[np.float64]:
    """A closed outline with optional arc segments, arcs sampled within CHORD_MM."""
    pts = [np.asarray(outline[0], float)]
    for i in range(1, len(outline)):
        p0, p1 = np.asarray(outline[i - 1], float), np.asarray(outline[i], float)
        arc = arc_centers[i - 1] if arc_centers and i - 1 < len(arc_centers) else None
        if arc is None:
            pts.append(p1)
            continue
        clockwise, center = arc
        sweep = _signed_sweep(p0, p1, np.asarray(center, float), clockwise)
        r = float(np.linalg.norm(p0 - np.asarray(center, float)))
        a0 = np.arctan2(*(p0 - center)[::-1])
        pts.extend(arc_points(np.asarray(center, float), r, a0, sweep, CHORD_MM)[1:])
    return np.array(pts)


def _signed_sweep(p0: npt.NDArray[np.float64], p1: npt.NDArray[np.float64], center: npt.NDArray[np.float64],
                  clockwise: bool) -> float:
    """Sweep (rad, negative clockwise) from p0 to p1 around ``center``; equal ends: a full turn."""
    a0 = np.arctan2(*(p0 - center)[::-1])
    a1 = np.arctan2(*(p1 - center)[::-1])
    ccw = (a1 - a0) % (2 * np.pi)
    if ccw == 0.0:
        ccw = 2 * np.pi
    return -(2 * np.pi - ccw if ccw < 2 * np.pi else 2 * np.pi) if clockwise else ccw


def _flash_pad(obj: go.Flash, source: Source, k: int) -> Pad:
    """The pad a flash stamps: its aperture's outline (dark minus clear primitives), mm."""
    dark: list[Polygon] = []
    clear: list[Polygon] = []
    for prim in obj.to_primitives(unit=MM):
        (dark if getattr(prim, "polarity_dark", True) else clear).append(_primitive_geometry(prim))
    shape = unary_union(dark)
    if clear:
        shape = shape.difference(unary_union(clear))
    if shape.geom_type != "Polygon":
        shape = max(getattr(shape, "geoms", [shape]), key=lambda g: g.area)
    ap = obj.aperture
    kind = _SHAPES.get(type(ap).__name__, getattr(getattr(ap, "macro", None), "name", "macro"))
    center = np.array([MM.convert_from(obj.unit, obj.x), MM.convert_from(obj.unit, obj.y)])
    return Pad(kind, center, ring_of(shape), source, f"flash {k}")


def _draw_width(obj: go.Line | go.Arc, name: str, k: int) -> float:
    """The width (mm) a draw's circular aperture gives its line."""
    try:
        return float(obj.aperture.equivalent_width(MM))
    except ValueError as exc:
        raise CircuitFileError(f"draw {k} uses a non-circular aperture (D{obj.aperture.original_number}): "
                               "its line width is undefined", file=name,
                               where=f"draw {k}, aperture D{obj.aperture.original_number}") from exc


def _draw_curve(obj: go.Line | go.Arc) -> NurbsCurve | None:
    """A draw as an exact curve in mm, None for a zero-length line."""
    o = obj.converted(MM)
    p0, p1 = np.array([o.x1, o.y1]), np.array([o.x2, o.y2])
    if isinstance(o, go.Arc):
        return arc_center(p0, p1, p0 + [o.cx, o.cy], bool(o.clockwise))
    if np.linalg.norm(p1 - p0) <= LENGTH_EPS_MM:
        return None
    return line(p0, p1)


def _net(obj: go.GraphicObject) -> str:
    """The Gerber X2 net name (%TO.N%) of an object, "" when absent."""
    attrs = getattr(obj, "attrs", None)
    value = attrs.get(".N") if isinstance(attrs, dict) else None
    if isinstance(value, (list, tuple)):
        value = ",".join(str(v) for v in value)
    return str(value or "")


def _function(obj: go.GraphicObject) -> str:
    """The X2 aperture function (``.AperFunction``: Conductor, SMDPad, ViaPad, NonConductor,
    Profile...) of a draw, flash or region; "" when the file does not say."""
    attrs = getattr(obj, "attrs", None)
    value = attrs.get(".AperFunction") if isinstance(attrs, dict) else None
    if value is None and getattr(obj, "aperture", None) is not None:
        value = dict(getattr(obj.aperture, "attrs", None) or ()).get(".AperFunction")
    if isinstance(value, (list, tuple)):
        value = value[0] if value else ""
    return str(value or "")


def _layer_name(gerber: GerberFile, name: str) -> str:
    """The X2 file function (%TF.FileFunction%) of a Gerber file, else the file name."""
    attrs = getattr(gerber, "file_attrs", None) or {}
    function = attrs.get(".FileFunction") if isinstance(attrs, dict) else None
    if function:
        return ",".join(function) if isinstance(function, (list, tuple)) else str(function)
    return name


def read_gerber(text: str, name: str, layer: str | None = None) -> Layout:
    """Traces, pads and areas of one Gerber file (a Gerber file is one layer)."""
    gerber = _parse(_load_gerber, text, name)
    layer_name = _layer_name(gerber, name)
    if layer and layer not in (layer_name, name) and not layer_name.startswith(layer):
        raise CircuitFileError(f"layer {layer!r} is not this Gerber file's layer ({layer_name!r})", file=name,
                               where=f"layer {layer}", field="layers")
    unit = getattr(getattr(gerber, "import_settings", None), "unit", None)
    out = Layout(file=name, format="gerber", units=getattr(unit, "name", "mm") if unit else "mm",
                 layers=(layer_name,))
    draws = flashes = 0
    profile = layer_name.startswith("Profile")            # a whole file of board outline
    edge: list[LineString] = []
    skipped: dict[str, int] = {}
    for obj in gerber.objects:
        function = "Profile" if profile else _function(obj)
        if function in NOT_PRINTED:
            if function == "Profile" and isinstance(obj, (go.Line, go.Arc)):
                curve = _draw_curve(obj)
                if curve is not None:
                    edge.append(LineString(curve.evaluate(np.linspace(*curve.domain, 2 if curve.degree == 1 else 65))))
            skipped[function] = skipped.get(function, 0) + 1
            continue
        if isinstance(obj, (go.Line, go.Arc)):
            draws += 1
            width = _draw_width(obj, name, draws)
            curve = _draw_curve(obj)
            src = Source(name, layer_name, _net(obj), width, f"draw {draws} (D{obj.aperture.original_number})")
            if curve is None:   # a zero-length draw stamps its aperture: a round pad
                flash = go.Flash(obj.x1, obj.y1, obj.aperture, unit=obj.unit)
                out.pads.append(_flash_pad(flash, src, draws))
                continue
            if not obj.polarity_dark:
                out.notes.append(f"draw {draws}: clear-polarity draw ignored")
                continue
            out.traces.append(LayoutTrace(curve, src))
        elif isinstance(obj, go.Flash):
            flashes += 1
            src = Source(name, layer_name, _net(obj), 0.0, f"flash {flashes} (D{obj.aperture.original_number})")
            pad = _flash_pad(obj, src, flashes)
            if function == "ViaPad":       # a via's land: an interconnect point, not a pad to fill
                span = pad.exterior.max(axis=0) - pad.exterior.min(axis=0)
                out.vias.append(Via(pad.center, float(span.max()), 0.0, src.net, (layer_name,)))
                continue
            out.pads.append(pad)
        elif isinstance(obj, go.Region):
            f = MM.convert_from(obj.unit, 1.0)
            outline = [(x * f, y * f) for x, y in obj.outline]
            arcs = [None if a is None else (a[0], (a[1][0] * f, a[1][1] * f)) for a in obj.arc_centers]
            ring = _outline_points(outline, arcs)
            poly = Polygon(ring).buffer(0)
            if not obj.polarity_dark or poly.is_empty:
                out.notes.append(f"region {len(out.areas) + 1}: clear or empty region ignored")
                continue
            geoms = getattr(poly, "geoms", [poly])
            for g in geoms:
                holes = tuple(np.asarray(h.coords)[:-1] for h in g.interiors)
                out.areas.append(Area(ring_of(g), holes, Source(name, layer_name, _net(obj), 0.0,
                                                                f"region {len(out.areas) + 1}")))
    out.outline = outline_rings(edge)
    out.notes += [f"{n} {function} object(s) (X2 aperture function) are not conductors: not printed"
                  + (" (the board outline: its boundary)" if function == "Profile" else "")
                  for function, n in skipped.items()]
    if out.vias:
        out.notes.append(f"{len(out.vias)} via pad(s) read: reported as interconnect points, not filled as pads")
    return out


def read_excellon(text: str, name: str, layer: str | None = None) -> Layout:
    """Drill hits as holes (``vias``: where the layers join, tool diameter), never pads to fill;
    routed slots are noted, not printed; mm."""
    drill = _parse(ExcellonFile.from_string, text, name)
    out = Layout(file=name, format="excellon", units="mm", layers=("drill",))
    slots = 0
    for obj in drill.objects:
        tool = obj.aperture
        dia = float(MM.convert_from(tool.unit, tool.diameter))
        if isinstance(obj, go.Flash):
            center = np.array([MM.convert_from(obj.unit, obj.x), MM.convert_from(obj.unit, obj.y)])
            out.vias.append(Via(center, dia, dia, "", ("drill",)))
        else:
            slots += 1
    if slots:
        out.notes.append(f"{slots} routed slot(s) are holes, not conductors: not printed")
    if out.vias:
        out.notes.append(f"{len(out.vias)} drill hit(s) read as holes (vias), not pads to fill")
    return out
