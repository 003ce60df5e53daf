"""KiCad ``.kicad_pcb`` boards (kiutils): tracks (segments and arcs) with width and net, and
pads with their shapes, on one chosen copper layer.

KiCad's y axis points down; the layout is the board seen from the top with y up, so every
coordinate is (X, -Y) and KiCad's angles (counter-clockwise on screen) stay as they are.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import numpy.typing as npt
from kiutils.board import Board
from kiutils.footprint import Footprint
from kiutils.items.common import Position
from kiutils.utils import sexpr
from shapely.geometry import LineString, Polygon
from shapely.geometry.base import BaseGeometry

from app.circuits.curves import arc_three_points, line
from app.circuits.errors import CircuitFileError
from app.circuits.kicad_graphics import copper_graphics
from app.circuits.kicad_pads import kicad_pad_outline
from app.circuits.layout import Area, Dropped, Layout, LayoutTrace, Pad, Source, Via, circle_ring, copper_side
from app.circuits.shapes import CHORD_MM, outline_rings, ring_of, rotate
from app.geometry.tolerance import LENGTH_EPS_MM

__all__ = ["read_kicad", "OLDEST_VERSION"]

#: the oldest board format read: KiCad 5's (its footprints are ``module`` items); KiCad 6, 7
#: and 8 boards (20211014 .. 2024xxxx) have ``footprint`` items and arcs
OLDEST_VERSION = 20171130

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


def _version(tree: list[Any], name: str) -> int:
    """The board's format version (a date, e.g. 20221018 for KiCad 7); CircuitFileError for one
    older than KiCad 5's (KiCad 4 and before: version 3, 4) or a file that is no board."""
    if not isinstance(tree, list) or not tree or tree[0] != "kicad_pcb":
        raise CircuitFileError("not a KiCad board (it does not start with kicad_pcb)", file=name, where="line 1")
    found = [item[1] for item in tree[1:] if isinstance(item, list) and len(item) > 1 and item[0] == "version"]
    try:
        version = int(found[0]) if found else 0
    except (TypeError, ValueError):
        version = 0
    if version < OLDEST_VERSION:
        raise CircuitFileError(f"KiCad board format version {found[0] if found else 'missing'} is older than "
                               f"KiCad 5 ({OLDEST_VERSION}): open and save it in KiCad 5 or newer first",
                               file=name, where=f"version {found[0] if found else 'missing'}")
    return version


def _rect_delta(pad: list[Any]) -> tuple[float, float] | None:
    """A pad s-expression's ``rect_delta`` (dx, dy) mm (trapezoids; kiutils does not read it)."""
    for item in pad:
        if isinstance(item, list) and len(item) >= 3 and item[0] == "rect_delta":
            return float(item[1]), float(item[2])
    return None


def _edge_rings(board: Board) -> list[npt.NDArray[np.float64]]:
    """The board outline (Edge.Cuts lines, arcs, rectangles, circles, polygons) as closed rings
    (k, 2) mm, y up, largest first."""
    lines: list[LineString] = []
    for item in board.graphicItems:
        if getattr(item, "layer", None) != "Edge.Cuts":
            continue
        kind = type(item).__name__
        if kind == "GrLine":
            lines.append(LineString([_up(item.start), _up(item.end)]))
        elif kind == "GrArc":
            curve = arc_three_points(_up(item.start), _up(item.mid), _up(item.end))
            lines.append(LineString(curve.evaluate(np.linspace(*curve.domain, 97))))
        elif kind == "GrRect":
            (x0, y0), (x1, y1) = _up(item.start), _up(item.end)
            lines.append(LineString([(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]))
        elif kind == "GrCircle":
            c = _up(item.center)
            lines.append(Polygon(circle_ring(c, float(np.linalg.norm(_up(item.end) - c)), CHORD_MM)).exterior)
        elif kind == "GrPoly":
            lines.append(Polygon([_up(p) for p in item.coordinates]).exterior)
    return outline_rings(lines)


def _without(tree: list[Any], token: str) -> list[Any]:
    """The s-expression tree less every list headed ``token`` (kiutils cannot read KiCad 7's
    ``render_cache``, the stored outline of a TrueType text; it is read from the tree)."""
    return [_without(item, token) if isinstance(item, list) else item for item in tree
            if not (isinstance(item, list) and item and item[0] == token)]


_INNER = re.compile(r"^(?:inner|in)\s*(\d+)$", re.IGNORECASE)


def _resolve_layer(layer: str) -> str:
    """A copper layer asked by its side (``top``, ``bottom``, ``inner<n>``) or its KiCad name."""
    inner = _INNER.match(layer.strip())
    return {"top": "F.Cu", "bottom": "B.Cu"}.get(layer.strip().lower(), f"In{inner.group(1)}.Cu" if inner else layer)


def _stack(board: Board, copper: tuple[str, ...], printed: str) -> list[dict[str, object]]:
    """Each copper layer (top to bottom): its side, whether it is printed, and its tracks, pads
    (NPTH holes not counted), zones and vias (a via joins every layer from its first to its last)."""
    order = {name: k for k, name in enumerate(copper)}
    tracks: dict[str, int] = {}
    spans = []
    for item in board.traceItems:
        kind = type(item).__name__
        if kind in ("Segment", "Arc"):
            tracks[item.layer] = tracks.get(item.layer, 0) + 1
        elif kind == "Via":
            ends = [order[name] for name in (item.layers or []) if name in order] or [0, len(copper) - 1]
            spans.append((min(ends), max(ends)))
    pads = [list(p.layers) for fp in board.footprints for p in fp.pads if p.type != "np_thru_hole"]
    return [{"layer": name, "side": copper_side(name), "printed": name == printed, "tracks": tracks.get(name, 0),
             "pads": sum(_on_layer(layers, name) for layers in pads),
             "zones": sum(name in (z.layers or []) for z in board.zones),
             "vias": sum(lo <= k <= hi for lo, hi in spans)} for k, name in enumerate(copper)]


def _reference(fp: Footprint) -> str:
    """A footprint's reference designator (else its library id)."""
    props = getattr(fp, "properties", None) or {}
    if isinstance(props, dict) and props.get("Reference"):
        return str(props["Reference"])
    for item in getattr(fp, "graphicItems", []):
        if getattr(item, "type", None) == "reference":
            return str(item.text)
    return str(getattr(fp, "libId", "") or "")


# one flat dispatch over cases; splitting it hides their order
def read_kicad(text: str, name: str, layer: str | None = None, graphics: bool = False) -> Layout:  # noqa: C901
    """Tracks and pads of ``layer`` (``top`` = F.Cu, the default; ``bottom`` = B.Cu; ``inner<n>``
    = In<n>.Cu; or a KiCad layer name) of a board; mm, y up; ``stack``: every copper layer counted.  Its copper
    graphics and text (:mod:`app.circuits.kicad_graphics`) are read when ``graphics`` asks,
    else only reported in the layout's ``skipped``.

    Raises CircuitFileError naming the line (unbalanced brackets), the entity, or the layer
    when it is not a copper layer of the board.
    """
    _check_brackets(text, name)
    tree = sexpr.parse_sexp(text)
    version = _version(tree, name)
    try:
        board = Board.from_sexpr(_without(tree, "render_cache") if "(render_cache" in text else tree)
        modules = [item for item in tree[1:] if isinstance(item, list) and item and item[0] in ("module", "footprint")]
        if not board.footprints:       # KiCad 5 calls its footprints modules; kiutils reads them one by one
            board.footprints = [Footprint.from_sexpr(item) for item in modules]
    except Exception as exc:   # kiutils raises bare Exceptions for bad structure
        raise CircuitFileError(f"not a KiCad board: {exc}", file=name, where="kicad_pcb") from exc
    deltas = [[_rect_delta(p) for p in item if isinstance(p, list) and p and p[0] == "pad"] for item in modules]
    copper = tuple(lt.name for lt in board.layers if lt.name.endswith(".Cu"))
    layer = _resolve_layer(layer or "top")
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
        if np.linalg.norm(end - start) <= LENGTH_EPS_MM and kind == "Segment":   # a dot: not a trace
            out.dropped.append(Dropped(np.vstack([start, end]), Source(name, layer, nets.get(item.net, ""), width,
                                                                       entity)))
            continue
        curve = line(start, end) if kind == "Segment" else arc_three_points(start, _up(item.mid), end)
        src = Source(name, layer, nets.get(item.net, ""), width, entity)
        out.traces.append(LayoutTrace(curve, src))
    holes = 0
    for f, fp in enumerate(board.footprints):
        fp_xy = _up(fp.position)
        fp_angle = np.radians(float(fp.position.angle or 0.0))
        ref = _reference(fp)
        for j, pad in enumerate(fp.pads):
            if not _on_layer(list(pad.layers), layer):
                continue
            if pad.type == "np_thru_hole":       # a bare hole (mounting, tooling): no copper to print
                holes += 1
                continue
            local = np.array([float(pad.position.X), -float(pad.position.Y)])
            center = fp_xy + rotate(local[None, :], fp_angle)[0]
            delta = deltas[f][j] if f < len(deltas) and j < len(deltas[f]) else None
            outline = kicad_pad_outline(pad, delta)
            # a pad's angle in a file is absolute (footprint's included) in every version read
            angle = np.radians(float(pad.position.angle or 0.0))
            net = pad.net.name if pad.net is not None else ""
            src = Source(name, layer, net, 0.0, f"pad {ref}.{pad.number}")
            out.pads.append(Pad(pad.shape, center, rotate(outline, angle) + center, src, f"{ref}.{pad.number}"))
    for k, zone in enumerate(board.zones):
        if layer not in (zone.layers or []) or zone.keepoutSettings is not None:
            continue
        filled = [fp for fp in zone.filledPolygons if fp.layer in (layer, None)]   # KiCad 5: no layer
        rings = [fp.coordinates for fp in filled] or [zp.coordinates for zp in zone.polygons]
        src = Source(name, layer, zone.netName or nets.get(zone.net, ""), 0.0,
                     f"zone {k} ({'filled' if filled else 'outline'})")
        for ring in rings:
            pts = np.array([[float(p.X), -float(p.Y)] for p in ring])
            if len(pts) >= 3:         # a filled polygon is fractured (holes joined by slits): unfold it
                out.areas += [Area(ring_of(g), tuple(np.asarray(h.coords)[:-1] for h in g.interiors), src)
                              for g in _polygons(Polygon(pts).buffer(0))]
    for item in board.traceItems:
        if type(item).__name__ == "Via" and ((item.type or "") not in ("blind", "micro") or layer in item.layers):
            out.vias.append(Via(_up(item.position), float(item.size), float(item.drill or 0.0),
                                nets.get(item.net, ""), tuple(item.layers)))
    out.outline = _edge_rings(board)
    out.stack = _stack(board, copper, layer)
    drawn = copper_graphics(tree, layer, name, read_text=graphics)
    if graphics:
        out.areas += drawn.areas
        out.traces += drawn.traces
        if drawn.texts or drawn.shapes:
            out.notes.append(f"{drawn.shapes} copper graphic(s) and {drawn.texts} copper text(s) on {layer} read as "
                             "copper")
        if drawn.unread:
            out.skipped.append(f"{len(drawn.unread)} copper graphic(s) or text(s) on {layer} not printed: "
                               f"{', '.join(drawn.unread[:5])}")
    elif drawn.texts or drawn.shapes:
        out.skipped.append(f"{drawn.shapes} copper graphic(s) and {drawn.texts} copper text(s) on {layer} not "
                           "printed (the import's copper_graphics option prints them)")
    if out.dropped:
        out.notes.append(f"{len(out.dropped)} zero-length track(s) (dots, e.g. {out.dropped[0].source.entity}): "
                         "not printed")
    if holes:
        out.notes.append(f"{holes} non-plated hole(s) (mounting, tooling) are not copper: not printed")
    if out.vias:
        out.notes.append(f"{len(out.vias)} via(s) read: reported as interconnect points, not filled as pads")
    if not (out.traces or out.pads or out.areas):
        raise CircuitFileError(f"nothing to print on {layer}: no tracks, pads or zones on that layer (board format "
                               f"{version})", file=name, where=f"layer {layer}", field="layers")
    return out
