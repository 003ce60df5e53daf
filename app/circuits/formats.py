"""Pick the importer for a file (by name, then by content) and run it.

Each importer's module (and its ECAD library: kiutils, gerbonara, ezdxf, svgelements) is
imported when a file of its format is read, not when the service starts: together they cost
about a second of every server, worker and compute-process start."""

from __future__ import annotations

import numpy as np

from app.circuits.budget import check_layout, precount, svg_items
from app.circuits.errors import CircuitFileError
from app.circuits.layout import RESOLUTION_MM, Dropped, Layout, LayoutTrace
from app.circuits.opens import curve_points, source_connections
from app.geometry.errors import GeometryError

__all__ = ["FORMATS", "MIN_TRACE_MM", "detect_format", "read_layout"]

#: the shortest trace that is printed (mm): a piece shorter than this (real boards hold 1 nm
#: segments from KiCad's editor, 1 um pieces in its DXF export) is below any printer's step
MIN_TRACE_MM = RESOLUTION_MM

FORMATS = ("kicad", "gerber", "excellon", "dxf", "svg")
_SUFFIXES = {".kicad_pcb": "kicad", ".gbr": "gerber", ".ger": "gerber", ".gtl": "gerber", ".gbl": "gerber",
             ".gts": "gerber", ".gbs": "gerber", ".gto": "gerber", ".gm1": "gerber", ".drl": "excellon",
             ".xln": "excellon", ".exc": "excellon", ".dxf": "dxf", ".svg": "svg"}


def detect_format(name: str, data: bytes) -> str:
    """The format of a file from its suffix, else from its first bytes; CircuitFileError if neither."""
    lower = name.lower()
    for suffix, fmt in _SUFFIXES.items():
        if lower.endswith(suffix):
            return fmt
    head = data[:4096].lstrip().decode("latin-1")
    if head.startswith("(kicad_pcb"):
        return "kicad"
    if head.startswith("M48") or head.startswith(";") and "M48" in head:
        return "excellon"
    if "%FS" in head or "%MO" in head or head.startswith("G04"):
        return "gerber"
    if "<svg" in head or head.startswith("<?xml") and "<svg" in data[:65536].decode("latin-1"):
        return "svg"
    if head.startswith("0") and "SECTION" in head[:200]:
        return "dxf"
    raise CircuitFileError(f"cannot tell the format of the file (name or first bytes); give format, one of "
                           f"{', '.join(FORMATS)}", file=name, field="format")


def _text(data: bytes, name: str) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        try:
            return data.decode("cp1252")      # old DXF and Gerber files
        except UnicodeDecodeError as exc:
            raise CircuitFileError(f"not a text file (byte {exc.start})", file=name, where=f"byte {exc.start}") \
                from exc


def _without_slivers(layout: Layout) -> Layout:
    """The layout less its traces no longer than :data:`MIN_TRACE_MM`, each named in a note
    (its neighbours meet within that length: nothing printable is lost)."""
    keep: list[LayoutTrace] = []
    dropped: list[LayoutTrace] = []
    for t in layout.traces:
        (keep if t.curve.length > MIN_TRACE_MM * (1 + 1e-6) else dropped).append(t)
    for t in dropped[:20]:
        layout.notes.append(f"{t.source.entity}: {t.curve.length:.3g} mm long, shorter than the {MIN_TRACE_MM} mm "
                            "resolution: dropped")
    if len(dropped) > 20:
        layout.notes.append(f"{len(dropped) - 20} more traces shorter than {MIN_TRACE_MM} mm dropped")
    layout.traces = keep
    layout.dropped += [Dropped(curve_points(t.curve), t.source) for t in dropped]
    return layout


def read_layout(data: bytes, name: str, fmt: str | None = None, layers: list[str] | None = None, *,
                graphics: bool = False, copper_layer: str | None = None) -> Layout:
    """A file's layout in mm (``fmt`` None = auto-detect), within the bounds of
    :mod:`app.circuits.budget` (counted before expanding, checked after).  ``layers``: KiCad
    copper layer (one), DXF layers, SVG group ids/labels, a Gerber file's function; None
    takes the default (KiCad F.Cu, everything else all); ``graphics``: a KiCad board's copper
    graphics and text are printed (else reported); ``copper_layer``: the KiCad copper layer
    printed (``top``, ``bottom``, ``inner<n>`` or its name; ``layers`` names it too).  Traces shorter than
    :data:`MIN_TRACE_MM` are dropped with a note; the layout's ``connections`` are its named
    nets' connected pieces as the file draws them (:func:`app.circuits.opens.source_connections`).

    An importer's library failing on numbers it cannot represent (an overflow, a singular
    transform) is a CircuitFileError naming the file, like any other unreadable file."""
    try:
        layout = _read(data, name, fmt, layers, graphics, copper_layer)
    except CircuitFileError:
        raise
    except (ArithmeticError, ValueError, TypeError, IndexError, KeyError, AttributeError, RecursionError,
            np.linalg.LinAlgError, GeometryError) as exc:
        message = getattr(exc, "message", None) or f"{type(exc).__name__}: {exc}"
        raise CircuitFileError(f"cannot read the file: {message}"[:300], file=name) from exc
    check_layout(layout)
    layout = _without_slivers(layout)
    layout.connections = source_connections(layout)
    return layout


def _read(data: bytes, name: str, fmt: str | None, layers: list[str] | None, graphics: bool = False,
          copper_layer: str | None = None) -> Layout:
    """The importer's layout of the file, as it reads it."""
    fmt = fmt or detect_format(name, data)
    if fmt not in FORMATS:
        raise CircuitFileError(f"unknown format {fmt!r}; one of {', '.join(FORMATS)}", file=name, field="format")
    if not data.strip():
        raise CircuitFileError("the file is empty", file=name)
    if fmt == "svg":
        from app.circuits.svg import read_svg

        svg_items(data, name)
        return read_svg(data, name, layers)
    text = _text(data, name)
    precount(fmt, text, name)
    if fmt == "kicad":
        if layers and len(layers) > 1:
            raise CircuitFileError("a KiCad import takes one copper layer", file=name, where=f"layer {layers[1]}",
                                   field="layers")
        from app.circuits.kicad import read_kicad

        if layers and copper_layer and layers[0] != copper_layer:
            raise CircuitFileError(f"layers {layers[0]!r} and layer {copper_layer!r} disagree: give one", file=name,
                                   where=f"layer {copper_layer}", field="layer")
        return read_kicad(text, name, layers[0] if layers else copper_layer, graphics)
    if fmt == "gerber":
        from app.circuits.gerber import read_gerber

        return read_gerber(text, name, layers[0] if layers else None)
    if fmt == "excellon":
        from app.circuits.gerber import read_excellon

        return read_excellon(text, name)
    from app.circuits.dxf import read_dxf

    return read_dxf(text, name, layers)
