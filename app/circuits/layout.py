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

__all__ = ["Source", "LayoutTrace", "Pad", "Area", "Via", "Layout", "circle_ring", "arc_points"]


@dataclass(frozen=True)
class Source:
    """Where an item came from: file name, layer, net ("" when none) and width (mm, 0 = none)."""

    file: str
    layer: str
    net: str = ""
    width_mm: float = 0.0
    entity: str = ""

    def to_dict(self) -> dict[str, str | float]:
        """API form (JSON values)."""
        return {"file": self.file, "layer": self.layer, "net": self.net, "width_mm": self.width_mm,
                "entity": self.entity}


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


@dataclass
class Layout:
    """Everything one file contributes; ``units`` names the file's own unit (converted to mm).
    ``vias``: interconnect points (not printed as pads); ``outline``: the board's edge as
    closed rings (k, 2) mm (KiCad Edge.Cuts, a Gerber profile): the boundary, not traces."""

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
