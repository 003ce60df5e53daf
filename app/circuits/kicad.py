"""KiCad ``.kicad_pcb`` boards (kiutils): tracks (segments and arcs) with width and net, and
pads with their shapes, on one chosen copper layer.

KiCad's y axis points down; the layout is the board seen from the top with y up, so every
coordinate is (X, -Y) and KiCad's angles (counter-clockwise on screen) stay as they are.
"""

from __future__ import annotations

import re

import numpy as np
import numpy.typing as npt
from kiutils.board import Board
from kiutils.footprint import Footprint
from kiutils.items.common import Position
from kiutils.utils import sexpr
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from app.circuits.curves import arc_three_points, line
from app.circuits.errors import CircuitFileError
from app.circuits.layout import Area, Layout, LayoutTrace, Pad, Source
from app.circuits.shapes import pad_outline, ring_of, rotate
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = ["read_kicad"]

_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[()]|\n')


def _check_brackets(text: str, name: str) -> None:
    """Raise naming the line of an unbalanced bracket (a truncated or damaged file)."""
    depth, line_no, opened = 0, 1, []
    for m in _TOKEN.finditer(text):
        tok = m.group()
        if tok == "\n":
            line_no += 1
        elif tok.startswith('"'):
            line_no += tok.count("\n")
        elif tok == "(":
            depth += 1
            opened.append(line_no)
        else:
            depth -= 1
            if depth < 0:
                raise CircuitFileError("unexpected ')'", file=name, where=f"line {line_no}")
            opened.pop()
    if depth:
        raise CircuitFileError(f"{depth} bracket(s) never closed: the file is truncated or damaged "
                               f"(the innermost opened at line {opened[-1]})", file=name,
                               where=f"line {opened[-1]}")


def _up(pos: Position) -> npt.NDArray[np.float64]:
    """A KiCad position (mm, y down) as XY mm with y up."""
    return np.array([float(pos.X), -float(pos.Y)])


def _on_layer(pad_layers: list[str], layer: str) -> bool:
    """Whether a pad on ``pad_layers`` (with wildcards like ``*.Cu``, ``F&B.Cu``) is on ``layer``."""
    side = layer.split(".", 1)[0]
    return any(pl == layer or pl == "*.Cu" or (pl.endswith(".Cu") and side in pl.split(".", 1)[0].split("&"))
               for pl in pad_layers)


def _polygons(geom: BaseGeometry) -> list[Polygon]:
    """The polygons (with area) of a shapely geometry."""
    return [g for g in getattr(geom, "geoms", [geom]) if isinstance(g, Polygon) and g.area > 0]


def _reference(fp: Footprint) -> str:
    """A footprint's reference designator (else its library id)."""
    props = getattr(fp, "properties", None) or {}
    if isinstance(props, dict) and props.get("Reference"):
        return str(props["Reference"])
    for item in getattr(fp, "graphicItems", []):
        if getattr(item, "type", None) == "reference":
            return str(item.text)
    return str(getattr(fp, "libId", "") or "")


def read_kicad(text: str, name: str, layer: str | None = None) -> Layout:
    """Tracks and pads of ``layer`` (default ``F.Cu``) of a board; mm, y up.

    Raises CircuitFileError naming the line (unbalanced brackets), the entity, or the layer
    when it is not a copper layer of the board.
    """
    _check_brackets(text, name)
    try:
        board = Board.from_sexpr(sexpr.parse_sexp(text))
    except Exception as exc:   # kiutils raises bare Exceptions for bad structure
        raise CircuitFileError(f"not a KiCad board: {exc}", file=name, where="kicad_pcb") from exc
    copper = tuple(lt.name for lt in board.layers if lt.name.endswith(".Cu"))
    layer = layer or "F.Cu"
    if copper and layer not in copper:
        raise CircuitFileError(f"layer {layer!r} is not a copper layer of the board (it has {', '.join(copper)})",
                               file=name, where=f"layer {layer}", field="layers")
    nets = {n.number: n.name for n in board.nets}
    out = Layout(file=name, format="kicad", units="mm", layers=copper)
    for k, item in enumerate(board.traceItems):
        kind = type(item).__name__
        if kind not in ("Segment", "Arc") or item.layer != layer:
            continue
        entity = f"{kind.lower()} {k} ({getattr(item, 'tstamp', '') or ''})".replace(" ()", "")
        width = float(item.width)
        if not np.isfinite(width) or width <= 0:
            raise CircuitFileError(f"track width {width} must be positive", file=name, where=entity)
        start, end = _up(item.start), _up(item.end)
        if np.linalg.norm(end - start) <= LENGTH_EPS_MM and kind == "Segment":
            continue
        curve = line(start, end) if kind == "Segment" else arc_three_points(start, _up(item.mid), end)
        src = Source(name, layer, nets.get(item.net, ""), width, entity)
        out.traces.append(LayoutTrace(curve, src))
    for fp in board.footprints:
        fp_xy = _up(fp.position)
        fp_angle = np.radians(float(fp.position.angle or 0.0))
        ref = _reference(fp)
        for pad in fp.pads:
            if not _on_layer(list(pad.layers), layer):
                continue
            local = np.array([float(pad.position.X), -float(pad.position.Y)])
            center = fp_xy + rotate(local[None, :], fp_angle)[0]
            w, h = float(pad.size.X), float(pad.size.Y or pad.size.X)
            radius = float(pad.roundrectRatio or 0.0) * min(w, h)
            outline = pad_outline(pad.shape, w, h, corner_radius=radius)
            angle = np.radians(float(pad.position.angle or 0.0))
            net = pad.net.name if pad.net is not None else ""
            src = Source(name, layer, net, 0.0, f"pad {ref}.{pad.number}")
            out.pads.append(Pad(pad.shape, center, rotate(outline, angle) + center, src, f"{ref}.{pad.number}"))
    for k, zone in enumerate(board.zones):
        if layer not in (zone.layers or []) or zone.keepoutSettings is not None:
            continue
        filled = [fp for fp in zone.filledPolygons if fp.layer == layer]
        rings = [fp.coordinates for fp in filled] or [zp.coordinates for zp in zone.polygons]
        src = Source(name, layer, zone.netName or nets.get(zone.net, ""), 0.0,
                     f"zone {k} ({'filled' if filled else 'outline'})")
        for ring in rings:
            pts = np.array([[float(p.X), -float(p.Y)] for p in ring])
            if len(pts) >= 3:         # a filled polygon is fractured (holes joined by slits): unfold it
                out.areas += [Area(ring_of(g), tuple(np.asarray(h.coords)[:-1] for h in g.interiors), src)
                              for g in _polygons(Polygon(pts).buffer(0))]
    return out
