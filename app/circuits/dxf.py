"""DXF drawings (ezdxf): LINE, ARC, CIRCLE, LWPOLYLINE and 2-D POLYLINE (with bulges), SPLINE (exact NURBS),
ELLIPSE (exact rational spline) and blocks placed by INSERT (nested, with their transforms).

Units come from the header's ``$INSUNITS`` (inch = 25.4 mm exactly; unitless files are read
as mm and say so in the layout's notes).  A trace's width is the polyline's constant width
or, else, the entity's lineweight (1/100 mm); 0 when neither is set.  Entities of a block
on layer "0" take the layer of the INSERT that places them (DXF's BYBLOCK rule).  Copper
drawn as closed zero-width outlines (an ECAD plot's outline mode) is read as areas with
their holes (:mod:`app.circuits.dxf_loops`).
"""

from __future__ import annotations

import io
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from ezdxf.entities.arc import Arc
from ezdxf.entities.circle import Circle
from ezdxf.entities.dxfgfx import DXFGraphic
from ezdxf.entities.ellipse import Ellipse
from ezdxf.entities.insert import Insert
from ezdxf.entities.line import Line
from ezdxf.entities.lwpolyline import LWPolyline
from ezdxf.entities.polyline import Polyline
from ezdxf.entities.spline import Spline
from ezdxf.filemanagement import read as read_dxf_stream
from ezdxf.lldxf.const import DXFError
from ezdxf.math import rational_bspline_from_ellipse

from app.circuits.budget import MAX_ITEMS, check_layout
from app.circuits.curves import arc_center, bulge_arc, concatenated, line
from app.circuits.dxf_loops import loops_as_areas
from app.circuits.errors import CircuitFileError
from app.circuits.layout import Layout, LayoutTrace, Source
from app.geometry.errors import GeometryError
from app.geometry.nurbs import NurbsCurve
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = ["read_dxf", "INSUNITS_MM"]

#: $INSUNITS code -> mm per drawing unit (exact factors)
INSUNITS_MM = {0: 1.0, 1: 25.4, 2: 304.8, 4: 1.0, 5: 10.0, 6: 1000.0, 8: 25.4e-6, 9: 0.0254, 10: 914.4,
               13: 1e-3, 14: 0.1}
#: deepest chain of blocks inserting blocks
MAX_NESTING = 64
_NAMES = {0: "unitless", 1: "inch", 2: "foot", 4: "mm", 5: "cm", 6: "m", 8: "microinch", 9: "mil", 10: "yard",
          13: "micron", 14: "decimetre"}


def _xy(v: Sequence[float], scale: float) -> npt.NDArray[np.float64]:
    """The XY of a DXF point, in mm."""
    return np.array([float(v[0]), float(v[1])]) * scale


def _width(entity: DXFGraphic, scale: float) -> float:
    """The entity's drawn width in mm: LWPOLYLINE constant width, else its lineweight (0: none)."""
    const = float(entity.dxf.get("const_width", 0.0) or 0.0) if entity.dxftype() == "LWPOLYLINE" else 0.0
    if const > 0:
        return const * scale
    lw = int(entity.dxf.get("lineweight", -1))
    return lw / 100.0 if lw > 0 else 0.0


def _lwpolyline(e: LWPolyline, scale: float) -> NurbsCurve | None:
    """A light-weight polyline (with bulges) as one exact curve in mm."""
    raw = [(x, y, b) for x, y, *_, b in e.get_points("xyseb")]
    return _bulge_path(e, raw, float(e.dxf.get("elevation", 0.0)), bool(e.closed), scale)


def _polyline2d(e: Polyline, scale: float) -> NurbsCurve | None:
    """An old-style 2-D POLYLINE (its VERTEX entities with bulges)."""
    raw = [(v.dxf.location[0], v.dxf.location[1], float(v.dxf.get("bulge", 0.0))) for v in e.vertices]
    elevation = float(e.dxf.get("elevation", (0.0, 0.0, 0.0))[2])
    return _bulge_path(e, raw, elevation, bool(e.is_closed), scale)


def _bulge_path(e: LWPolyline | Polyline, raw: list[tuple[float, float, float]], elevation: float, closed: bool,
                scale: float) -> NurbsCurve | None:
    """Vertices (x, y, bulge) in the entity's OCS -> one exact curve (lines and arcs) in mm."""
    ocs = e.ocs()
    flip = e.dxf.extrusion[2] < 0
    pts = [np.array(tuple(ocs.to_wcs((x, y, elevation)))[:2], float) * scale for x, y, _ in raw]
    bulges = [(-b if flip else b) for _, _, b in raw]
    if closed:
        pts.append(pts[0])
        bulges.append(0.0)
    pieces: list[NurbsCurve] = []
    for i in range(len(pts) - 1):
        if np.linalg.norm(pts[i + 1] - pts[i]) <= LENGTH_EPS_MM:
            continue
        pieces.append(bulge_arc(pts[i], pts[i + 1], bulges[i]) if bulges[i] else line(pts[i], pts[i + 1]))
    return concatenated(pieces) if pieces else None


def _arc(e: Circle, scale: float) -> NurbsCurve:
    """An ARC, or a CIRCLE as a full circle, in mm (a mirrored OCS turns it clockwise)."""
    ocs = e.ocs()
    center = np.array(tuple(ocs.to_wcs(e.dxf.center))[:2], float) * scale
    if isinstance(e, Arc):
        start, end = _xy(e.start_point, scale), _xy(e.end_point, scale)
    else:
        start = end = center + [float(e.dxf.radius) * scale * (-1.0 if e.dxf.extrusion[2] < 0 else 1.0), 0.0]
    return arc_center(start, end, center, clockwise=e.dxf.extrusion[2] < 0)


def _spline(e: Spline, scale: float) -> NurbsCurve:
    """A SPLINE (control points, or fit points through ezdxf's interpolation) in mm."""
    if e.control_point_count() == 0:
        tool = e.construction_tool()     # fit points only: ezdxf's interpolating B-spline
        cps, knots, weights, degree = tool.control_points, tool.knots(), tool.weights(), tool.degree
    else:
        cps, knots, weights, degree = e.control_points, e.knots, e.weights, e.dxf.degree
    pts = np.array([[p[0], p[1]] for p in cps], float) * scale
    w = np.asarray(weights, float) if len(weights) else None
    return NurbsCurve(int(degree), np.asarray(knots, float), pts, w)


def _ellipse(e: Ellipse, scale: float) -> NurbsCurve:
    """An ELLIPSE as ezdxf's exact rational B-spline, in mm."""
    spline = rational_bspline_from_ellipse(e.construction_tool())
    pts = np.array([[p[0], p[1]] for p in spline.control_points], float) * scale
    return NurbsCurve(spline.degree, np.asarray(spline.knots(), float), pts, np.asarray(spline.weights(), float))


def _entities(layout: Iterable[DXFGraphic], parent_layer: str | None = None,
              path: str = "") -> Iterator[tuple[DXFGraphic, str, str]]:
    """(entity, effective layer, its INSERT path) for every drawable entity, block references
    expanded (nested, each with its transform)."""
    for e in layout:
        layer = e.dxf.get("layer", "0")
        if parent_layer is not None and layer == "0":
            layer = parent_layer
        if e.dxftype() == "INSERT" and isinstance(e, Insert):
            label = f"{path}INSERT {e.dxf.get('name', '?')} #{e.dxf.get('handle') or '-'} > "
            yield from _entities(e.virtual_entities(), layer, label)
        else:
            yield e, layer, path


def _count(layout: Iterable[DXFGraphic], blocks: Any, name: str, memo: dict[str, int],
           stack: tuple[str, ...] = ()) -> int:
    """Drawn items ``layout`` expands into (polyline vertices, spline points, block contents
    once per INSERT and MINSERT cell), counted without expanding; CircuitFileError past
    MAX_ITEMS, on a block that inserts itself, or nested deeper than MAX_NESTING."""
    total = 0
    for e in layout:
        kind = e.dxftype()
        if kind == "INSERT":
            block = str(e.dxf.get("name", ""))
            if block in stack:
                raise CircuitFileError(f"block {block!r} inserts itself", file=name, where=f"block {block}")
            if len(stack) >= MAX_NESTING:
                raise CircuitFileError(f"blocks nested deeper than {MAX_NESTING}", file=name, where=f"block {block}")
            if block not in memo:
                inner = blocks.get(block)
                memo[block] = 0 if inner is None else _count(inner, blocks, name, memo, (*stack, block))
            cells = max(1, int(e.dxf.get("row_count", 1))) * max(1, int(e.dxf.get("column_count", 1)))
            total += 1 + cells * memo[block]
        elif kind == "LWPOLYLINE":
            total += 1 + len(e)  # type: ignore[arg-type]
        elif kind == "POLYLINE":
            total += 1 + len(getattr(e, "vertices", ()))
        elif kind == "SPLINE":
            total += 1 + len(getattr(e, "control_points", ())) + len(getattr(e, "fit_points", ()))
        else:
            total += 1
        if total > MAX_ITEMS:
            raise CircuitFileError(f"the drawing expands into more than {MAX_ITEMS} entities and vertices "
                                   "(block references counted); split it or simplify it", file=name,
                                   where="INSERT" if stack else "modelspace", field="files")
    return total


def read_dxf(text: str, name: str, layers: list[str] | None = None) -> Layout:
    """Traces of the chosen ``layers`` (all when None) of a DXF drawing, in mm."""
    if "EOF" not in text[-200:]:
        raise CircuitFileError("the file ends without its EOF marker: truncated", file=name,
                               where=f"line {len(text.splitlines())}")
    try:
        doc = read_dxf_stream(io.StringIO(text))
    except (DXFError, ValueError, KeyError, IndexError) as exc:
        raise CircuitFileError(f"not a readable DXF: {exc}", file=name) from exc
    code = int(doc.header.get("$INSUNITS", 0))
    if code not in INSUNITS_MM:
        raise CircuitFileError(f"$INSUNITS {code} is not a length unit this importer knows", file=name,
                               where="header $INSUNITS")
    scale = INSUNITS_MM[code]
    out = Layout(file=name, format="dxf", units=_NAMES[code])
    if code == 0:
        out.notes.append("$INSUNITS is 0 (unitless): read as mm")
    _count(doc.modelspace(), doc.blocks, name, {})
    items = list(_entities(doc.modelspace()))
    present = sorted({layer for _, layer, _ in items})
    out.layers = tuple(present)
    if layers:
        missing = [lay for lay in layers if lay not in present]
        if missing:
            raise CircuitFileError(f"layer {missing[0]!r} has no entities (the drawing's layers: {', '.join(present)})",
                                   file=name, where=f"layer {missing[0]}", field="layers")
    for e, layer, path in items:
        if layers and layer not in layers:
            continue
        kind = e.dxftype()
        handle = e.dxf.get("handle") or "-"
        entity = f"{path}{kind} #{handle} on layer {layer}"
        try:
            # the type name picks the reader (a HELIX is a Spline subclass, not read); isinstance types it
            curve: NurbsCurve | None
            if kind == "LINE" and isinstance(e, Line):
                p0, p1 = _xy(e.dxf.start, scale), _xy(e.dxf.end, scale)
                curve = line(p0, p1) if np.linalg.norm(p1 - p0) > LENGTH_EPS_MM else None
            elif kind in ("ARC", "CIRCLE") and isinstance(e, Circle):  # an Arc is a Circle
                curve = _arc(e, scale)
            elif kind == "LWPOLYLINE" and isinstance(e, LWPolyline):
                curve = _lwpolyline(e, scale)
            elif kind == "POLYLINE" and isinstance(e, Polyline) and e.is_2d_polyline:
                curve = _polyline2d(e, scale)
            elif kind == "SPLINE" and isinstance(e, Spline):
                curve = _spline(e, scale)
            elif kind == "ELLIPSE" and isinstance(e, Ellipse):
                curve = _ellipse(e, scale)
            else:
                continue
        except (GeometryError, ValueError, ZeroDivisionError, DXFError) as exc:
            raise CircuitFileError(f"cannot use this entity: {getattr(exc, 'message', exc)}", file=name,
                                   where=entity) from exc
        if curve is None:
            continue
        out.traces.append(LayoutTrace(curve, Source(name, layer, "", _width(e, scale), entity)))
    check_layout(out, count=False)       # finite, bounded numbers before the loops are traced
    before = len(out.traces)
    out.traces, out.areas, loops = loops_as_areas(out.traces)
    if loops:
        holes = sum(len(a.holes) for a in out.areas)
        out.notes.append(f"{before - len(out.traces)} zero-width curves close into {loops} outline loop(s): read as "
                         f"{len(out.areas)} copper area(s) with {holes} hole(s), not as traces")
    return out
