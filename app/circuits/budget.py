"""Bounds on what one circuit file may expand into, counted before it is expanded.

An ECAD file is small on disk and large once read: a DXF block inserted by blocks that
are inserted by blocks, an SVG ``<use>`` of a ``<use>``, a Gerber step-and-repeat, a
million region vertices.  Each importer's input is counted here on its raw text (or on
its parsed but unexpanded structure) against :data:`MAX_ITEMS`, and what it produced is
checked by :func:`check_layout` (shape count, finite coordinates within
:data:`MAX_COORD_MM`, widths, total drawn length), so the cost of mapping a layout is
bounded by the numbers below whatever the file says.

Every refusal is a :class:`~app.circuits.errors.CircuitFileError` (422) naming the file
and what was counted.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from app.circuits.errors import CircuitFileError
from app.circuits.layout import Layout

__all__ = ["MAX_ITEMS", "MAX_SHAPES", "MAX_COORD_MM", "MAX_WIDTH_MM", "MAX_DRAWN_MM", "precount",
           "svg_items", "check_layout"]

#: drawn items one file may expand into (entities after block expansion, path segments,
#: flashes and draws after step-and-repeat, region vertices, drill hits)
MAX_ITEMS = 100_000
#: statements of a Gerber file, lines of an Excellon file (each item is one; the rest is
#: the header, apertures, tools and comments)
MAX_STATEMENTS = MAX_ITEMS + 20_000
#: traces, pads and areas of one import (every file together): a 20,000-track board with
#: its pads (real boards reach 4,000-15,000 tracks); each becomes a stored trace or probe
#: ring, so this also bounds a closed loop over an import (``MAX_FIELD_TRACES``)
MAX_SHAPES = 20_000
#: largest |coordinate| of a layout, mm (10 m: beyond any part a machine holds)
MAX_COORD_MM = 10_000.0
#: widest trace, pad-tool or line width, mm
MAX_WIDTH_MM = 100.0
#: total length of a file's traces (control polygons), mm: what mapping samples every 0.25 mm
MAX_DRAWN_MM = 250_000.0

_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
# %SR (repeat x, y) | G36/G37 | coordinates with D01/D02/D03 | a bare D01-D03 | modal coordinates
_GERBER_TOKEN = re.compile(r"%SR(?:X(\d+))?(?:Y(\d+))?|G3([67])\*|([XY][-+]?\d[^*%D]*)?D0?([123])\*"
                           r"|([XY][-+]?\d[^*%D]*)\*")
_EXCELLON_REPEAT = re.compile(r"^R(\d+)")


def _over(name: str, what: str, count: int | str, limit: int) -> CircuitFileError:
    return CircuitFileError(f"the file expands into more than {limit} {what} ({count}); split it or simplify it",
                            file=name, where=what, field="files")


def _gerber(text: str, name: str) -> None:
    """Draws and flashes (times the active step-and-repeat; outside regions they are traces
    and pads) and region vertices, counted statement by statement up to the bounds."""
    statements = text.count("*")
    if statements > MAX_STATEMENTS:
        raise _over(name, "statements", statements, MAX_STATEMENTS)
    items = shapes = 0
    repeat = 1
    op = "1"
    in_region = False
    for m in _GERBER_TOKEN.finditer(text):
        sr_x, sr_y, region, coords, code, modal = m.groups()
        if region is not None:
            in_region = region == "6"
            continue
        if coords is None and code is None and modal is None:  # %SR: a new repeat (or its end)
            repeat = max(1, int(sr_x or 1)) * max(1, int(sr_y or 1))
            if repeat > MAX_ITEMS:
                raise _over(name, "step-and-repeat copies", repeat, MAX_ITEMS)
            continue
        op = code or op
        if coords is None and modal is None:
            continue
        items += repeat
        if op != "2" and not in_region:
            shapes += repeat
        if items > MAX_ITEMS:
            raise _over(name, "draws, flashes and region vertices", f"over {MAX_ITEMS}", MAX_ITEMS)
        if shapes > MAX_SHAPES:
            raise _over(name, "draws and flashed pads", f"over {MAX_SHAPES}", MAX_SHAPES)


def _excellon(text: str, name: str) -> None:
    """Drill hits and routed slots (with repeat codes) count as pads."""
    lines = text.count("\n")
    if lines > MAX_STATEMENTS:
        raise _over(name, "lines", lines, MAX_STATEMENTS)
    hits = 0
    for line in text.splitlines():
        line = line.strip()
        repeat = _EXCELLON_REPEAT.match(line)
        if repeat is not None:
            hits += int(repeat.group(1))
        elif line[:1] in ("X", "Y") or line.startswith(("G85", "G00X", "G01X", "G00Y", "G01Y")):
            hits += 1
        if hits > MAX_SHAPES:
            raise _over(name, "drill hits", f"over {hits}", MAX_SHAPES)


def _kicad(text: str, name: str) -> None:
    """Tracks, pads and polygon vertices of a board."""
    items = sum(text.count(token) for token in ("(segment", "(arc", "(pad ", "(xy ", "(gr_"))
    if items > MAX_ITEMS:
        raise _over(name, "tracks, pads and outline vertices", items, MAX_ITEMS)


def precount(fmt: str, text: str, name: str) -> None:
    """Refuse a Gerber, Excellon or KiCad file whose counted items pass the bounds (DXF and
    SVG are counted on their parsed structure: :func:`app.circuits.dxf.read_dxf`,
    :func:`svg_items`)."""
    if fmt == "gerber":
        _gerber(text, name)
    elif fmt == "excellon":
        _excellon(text, name)
    elif fmt == "kicad":
        _kicad(text, name)


def _numbers(text: str | None, stop: int) -> int:
    """How many numbers ``text`` holds, counting no further than ``stop``."""
    if not text:
        return 0
    n = 0
    for _ in _NUMBER.finditer(text):
        n += 1
        if n > stop:
            break
    return n


def svg_items(data: bytes, name: str) -> int:
    """Elements plus path/point numbers an SVG expands into, ``<use>`` references followed
    (each time they are used); CircuitFileError past :data:`MAX_ITEMS` or on a reference
    cycle.  Computed bottom-up over the element tree, without expanding anything."""
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        line, column = exc.position
        raise CircuitFileError(f"not a readable SVG: {exc}", file=name, where=f"line {line}, column {column}") \
            from exc
    by_id = {el.get("id"): el for el in root.iter() if el.get("id")}
    cost: dict[int, int] = {}
    state: dict[int, int] = {}  # 1: on the stack, 2: done

    def refs(el: ET.Element) -> Iterable[ET.Element]:
        yield from el
        if el.tag.rsplit("}", 1)[-1] == "use":
            href = el.get("href") or el.get("{http://www.w3.org/1999/xlink}href") or ""
            target = by_id.get(href[1:]) if href.startswith("#") else None
            if target is not None:
                yield target

    stack: list[tuple[ET.Element, bool]] = [(root, False)]
    while stack:
        el, expanded = stack.pop()
        key = id(el)
        if expanded:
            total = 1 + _numbers(el.get("d"), MAX_ITEMS) + _numbers(el.get("points"), MAX_ITEMS)
            total += sum(cost[id(child)] for child in refs(el))
            if total > MAX_ITEMS:
                raise _over(name, "elements and path numbers (with <use> copies)", f"over {MAX_ITEMS}", MAX_ITEMS)
            cost[key] = total
            state[key] = 2
            continue
        if state.get(key) == 2:
            continue
        if state.get(key) == 1:
            raise CircuitFileError("a <use> refers to itself (directly or through its children)", file=name,
                                   where=f"<{el.tag.rsplit('}', 1)[-1]}> {el.get('id') or ''}".strip())
        state[key] = 1
        stack.append((el, True))
        for child in refs(el):
            if state.get(id(child)) == 1:
                raise CircuitFileError("a <use> refers to itself (directly or through its children)", file=name,
                                       where=f"<use> {el.get('id') or ''}".strip())
            if state.get(id(child)) != 2:
                stack.append((child, False))
    return cost[id(root)]


def _bounded(points: npt.NDArray[np.float64], name: str, where: str, field: str) -> None:
    if points.size and not (np.isfinite(points).all() and float(np.abs(points).max()) <= MAX_COORD_MM):
        bad = points[~np.isfinite(points)] if not np.isfinite(points).all() else points[np.abs(points) > MAX_COORD_MM]
        raise CircuitFileError(f"{field} {float(bad.flat[0])!r} is not a finite number within +-{MAX_COORD_MM:g} mm",
                               file=name, where=where, field=field)


def _width(width: float, name: str, where: str) -> None:
    if not (np.isfinite(width) and 0.0 <= width <= MAX_WIDTH_MM):
        raise CircuitFileError(f"width {width!r} mm is not a finite number in [0, {MAX_WIDTH_MM:g}]", file=name,
                               where=where, field="width_mm")


def check_layout(layout: Layout, *, count: bool = True) -> None:
    """Every number of ``layout`` finite and bounded, its shape count (unless not ``count``)
    and drawn length within the bounds; CircuitFileError naming the entity and the field otherwise."""
    name = layout.file
    shapes = len(layout.traces) + len(layout.pads) + len(layout.areas)
    if count and shapes > MAX_SHAPES:
        raise _over(name, "traces, pads and areas", shapes, MAX_SHAPES)
    drawn = 0.0
    for t in layout.traces:
        curve = t.curve
        _bounded(np.asarray(curve.control_points, float), name, t.source.entity, "coordinate")
        weights = np.asarray(curve.w, float)
        if not (np.isfinite(weights).all() and float(weights.min(initial=1.0)) > 0.0):
            raise CircuitFileError("a curve weight is not a finite positive number", file=name,
                                   where=t.source.entity, field="weight")
        _width(float(t.source.width_mm), name, t.source.entity)
        drawn += float(np.linalg.norm(np.diff(curve.control_points, axis=0), axis=1).sum())
        if drawn > MAX_DRAWN_MM:
            raise _over(name, "mm of drawn traces", f"over {drawn:.0f}", int(MAX_DRAWN_MM))
    for p in layout.pads:
        where = p.source.entity or p.name
        _bounded(np.asarray(p.center, float), name, where, "coordinate")
        _bounded(np.asarray(p.exterior, float), name, where, "coordinate")
        _width(float(p.source.width_mm), name, where)
    for a in layout.areas:
        for ring in (a.exterior, *a.holes):
            _bounded(np.asarray(ring, float), name, a.source.entity, "coordinate")
    for k, v in enumerate(layout.vias):
        where = f"via {k}"
        _bounded(np.asarray(v.center, float), name, where, "coordinate")
        _width(float(v.diameter_mm), name, where)
        _width(float(v.drill_mm), name, where)
