"""The flat layout an importer returns: traces, pads and areas in mm (top view, y up).

Traces are exact curves (:class:`~app.geometry.nurbs.NurbsCurve`, 2-D): lines and
polylines degree 1, circular arcs rational quadratic, splines as given.  Pads and areas are
polygons: ``exterior`` (k, 2) mm, counter-clockwise, not repeating the first point;
``holes`` clockwise rings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from app.geometry.nurbs import NurbsCurve

#: floor (rad) of an arc's angular step so that its point count stays finite
_MIN_ARC_STEP_RAD = 1e-9
#: the machine's resolution (mm): a trace no longer than this is not printed, and copper
#: closer than this counts as joined
RESOLUTION_MM = 0.001

__all__ = ["copper_side", "Source", "LayoutTrace", "Pad", "Area", "Via", "Dropped", "Connection", "Layout",
           "circle_ring", "arc_points", "RESOLUTION_MM"]


def copper_side(layer: str) -> str:
    """Where a copper layer lies in the board's stack: ``top``, ``bottom`` or ``inner`` (KiCad
    F.Cu / B.Cu / In<n>.Cu; Gerber X2 file functions Copper,L<n>,Top / Bot / Inr), "" for a
    layer that names no copper side (a DXF or SVG layer, a Gerber file without X2)."""
    if layer == "F.Cu" or layer.startswith("Copper,") and layer.endswith(",Top"):
        return "top"
    if layer == "B.Cu" or layer.startswith("Copper,") and layer.endswith(",Bot"):
        return "bottom"
    if layer.startswith("In") and layer.endswith(".Cu") or layer.startswith("Copper,") and ",Inr" in layer:
        return "inner"
    return ""


@dataclass(frozen=True)
class Source:
    """Where an item came from: file name, layer, net ("" when none) and width (mm, 0 = none)."""

    file: str
    layer: str
    net: str = ""
    width_mm: float = 0.0
    entity: str = ""

    def to_dict(self) -> dict[str, str | float]:
        """API form (JSON values); ``side``: the layer's place in the stack (:func:`copper_side`)."""
        return {"file": self.file, "layer": self.layer, "side": copper_side(self.layer), "net": self.net,
                "width_mm": self.width_mm, "entity": self.entity}


@dataclass(frozen=True)
class LayoutTrace:
    """A conductor: ``curve`` 2-D mm, drawn with ``source.width_mm``."""

    curve: NurbsCurve
    source: Source

    @property
    def width_mm(self) -> float:
        return self.source.width_mm


@dataclass(frozen=True)
class Pad:
    """A flashed pad: ``shape`` (circle, rect, oval, roundrect, polygon...), ``center`` (2,) mm,
    ``exterior`` (k, 2) mm polygon of its outline."""

    shape: str
    center: npt.NDArray[np.float64]
    exterior: npt.NDArray[np.float64]
    source: Source
    name: str = ""


@dataclass(frozen=True)
class Area:
    """A filled region (copper pour, Gerber region, closed DXF/SVG shape with fill)."""

    exterior: npt.NDArray[np.float64]
    holes: tuple[npt.NDArray[np.float64], ...]
    source: Source


@dataclass(frozen=True)
class Via:
    """A plated hole joining copper layers: ``center`` (2,) mm, copper ``diameter_mm``, ``drill_mm``
    (0 when unknown), its net and the layers it joins.  Not a pad: it is reported, not filled."""

    center: npt.NDArray[np.float64]
    diameter_mm: float
    drill_mm: float
    net: str = ""
    layers: tuple[str, ...] = ()


@dataclass(frozen=True)
class Dropped:
    """Copper the file holds that is not printed (a zero-length track: a dot of its width; a
    sliver shorter than :data:`RESOLUTION_MM`): ``points`` (k, 2) mm of its centre line.  Kept
    so that what the source board connects is known."""

    points: npt.NDArray[np.float64]
    source: Source


@dataclass(frozen=True)
class Connection:
    """Items of one named net that the source board connects (one connected piece of its
    copper, dropped copper and via lands included): indices into the layout's ``traces``,
    ``pads`` and ``areas``.  Only pieces of two or more printed items are kept."""

    net: str
    traces: tuple[int, ...] = ()
    pads: tuple[int, ...] = ()
    areas: tuple[int, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """JSON form (stored with the import)."""
        return {"net": self.net, "traces": list(self.traces), "pads": list(self.pads), "areas": list(self.areas)}


@dataclass
class Layout:
    """Everything one file contributes; ``units`` names the file's own unit (converted to mm).
    ``vias``: interconnect points (not printed as pads); ``outline``: the board's edge as
    closed rings (k, 2) mm (KiCad Edge.Cuts, a Gerber profile): the boundary, not traces.
    ``dropped``: copper read but not printed; ``skipped``: what the file holds that is not
    printed unless the import asks (each a sentence, a warning of the import); ``stack``: each
    copper layer of the file (name, side, printed or not, its tracks, pads, zones and vias
    counted); ``connections``: the named nets' connected
    pieces as the file draws them (see :mod:`app.circuits.opens`)."""

    file: str
    format: str
    units: str
    traces: list[LayoutTrace] = field(default_factory=list)
    pads: list[Pad] = field(default_factory=list)
    areas: list[Area] = field(default_factory=list)
    vias: list[Via] = field(default_factory=list)
    outline: list[npt.NDArray[np.float64]] = field(default_factory=list)
    layers: tuple[str, ...] = ()
    notes: list[str] = field(default_factory=list)
    dropped: list[Dropped] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    stack: list[dict[str, object]] = field(default_factory=list)
    connections: list[Connection] = field(default_factory=list)

    def bounds(self) -> npt.NDArray[np.float64]:
        """[[xmin, ymin], [xmax, ymax]] mm over trace control points and pad/area outlines."""
        pts = [t.curve.control_points for t in self.traces] + [p.exterior for p in self.pads]
        pts += [a.exterior for a in self.areas]
        if not pts:
            return np.zeros((2, 2))
        allp = np.vstack(pts)
        return np.array([allp.min(axis=0), allp.max(axis=0)])


def arc_points(center: npt.NDArray[np.float64], radius: float, a0: float, sweep: float,
               chord_mm: float) -> npt.NDArray[np.float64]:
    """Points (k, 2) on a circular arc from angle a0 by ``sweep`` rad (signed), every chord's
    sagitta <= chord_mm; endpoints included."""
    if radius <= 0:
        return np.asarray(center, float)[None, :]
    step = 2.0 * np.arccos(max(-1.0, 1.0 - chord_mm / radius)) if chord_mm < radius else np.pi / 2
    n = max(2, int(np.ceil(abs(sweep) / max(step, _MIN_ARC_STEP_RAD))) + 1)
    ang = a0 + np.linspace(0.0, sweep, n)
    return np.asarray(center, float) + radius * np.column_stack([np.cos(ang), np.sin(ang)])


def circle_ring(center: npt.NDArray[np.float64], radius: float, chord_mm: float = 0.001) -> npt.NDArray[np.float64]:
    """A full circle as a CCW polygon (k, 2) without the repeated first point."""
    return arc_points(center, radius, 0.0, 2 * np.pi, chord_mm)[:-1]
