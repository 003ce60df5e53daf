"""What one focus (a part or a job) shows, as arrays: built by the loaders, drawn by
:mod:`app.viewer.scenes`.  All lengths mm, in part (workpiece) coordinates."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.viewer.gcode_paths import ToolpathSegments
from app.viewer.layer_preview import ProgramPreview


@dataclass(frozen=True)
class Polyline:
    """A curve drawn as a polyline: points (k, 3) mm; role "nominal" or "reconstructed"."""

    name: str
    points: np.ndarray
    role: str = "nominal"


@dataclass(frozen=True)
class ProbeSet:
    """Probe points: planned (n, 3) and/or measured (m, 3) mm; deviation_mm (m,) signed,
    measured minus nominal along z, colours the measured points."""

    name: str
    planned: np.ndarray | None = None
    measured: np.ndarray | None = None
    deviation_mm: np.ndarray | None = None


@dataclass(frozen=True)
class Toolpath:
    """A program's moves; role "nominal", "compensated" or "warning" (moves to point out: drawn
    red, wider than the traces under them).  ``standoff_error_mm`` (m,), one
    per move (NaN where unknown, e.g. travel): the tip's height above the real (rebuilt)
    surface minus the set standoff; the dispensed moves are then coloured by it."""

    name: str
    segments: ToolpathSegments
    role: str = "nominal"
    standoff_error_mm: np.ndarray | None = None


@dataclass(frozen=True)
class LayerStack:
    """Layers for a slider: per layer a (m_i, 2, 3) array of segments (mm) and a label."""

    name: str
    labels: tuple[str, ...]
    segments: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class AxisGlyphs:
    """Nozzle axes along a five-axis path: positions (n, 3) mm, unit directions (n, 3)."""

    name: str
    positions: np.ndarray
    directions: np.ndarray
    length_mm: float


@dataclass(frozen=True)
class HeightStack:
    """Height maps for a slider: heights (k, L, W) mm on a grid of pitch_mm, cell (0, 0)
    at origin_xy; labels (k,) name the layer of each snapshot."""

    name: str
    heights: np.ndarray
    pitch_mm: float
    labels: tuple[str, ...]
    origin_xy: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class SurfaceMesh:
    """A triangle surface (e.g. a fitted NURBS surface): vertices (v, 3) mm, faces (f, 3)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True)
class ScalarSurface:
    """A triangle surface coloured by a value per vertex (a field's posterior sd; or, with
    ``signed``, the rebuilt deviation as a ribbon on the part along a trace): vertices (v, 3)
    mm, faces (f, 3), values (v,) in ``unit``, coloured from lo to hi (signed: one symmetric
    scale shared with the scene's other signed values)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    values: np.ndarray
    lo: float
    hi: float
    unit: str = "mm"
    signed: bool = False  # a signed deviation (diverging colours about 0) rather than a magnitude


@dataclass(frozen=True)
class DeviationPlot:
    """Measured minus nominal height along a trace: s_mm (n,) arc length, dz_mm (n,)."""

    name: str
    title: str
    s_mm: np.ndarray
    dz_mm: np.ndarray


@dataclass(frozen=True)
class ResidualMap:
    """Verification residuals of a closed loop shown on the part.

    points (k, 3) mm: each verification touch on its trace's nominal, lifted by the measured
    deviation; residual_mm (k,) measured - predicted deviation; limit_mm (k,) the band the
    residual had to stay within; flagged (k,) bool: outside its band, or the correction does
    not help there (the compensated program would be worse than the nominal one);
    trace_ids (k,) the touch's trace (None off the traces)."""

    name: str
    points: np.ndarray
    residual_mm: np.ndarray
    limit_mm: np.ndarray
    flagged: np.ndarray
    trace_ids: tuple[str | None, ...] = ()


@dataclass(frozen=True)
class FocusScene:
    """Everything one focus shows.  ``focus`` is {"part_id": ...} or {"job_id": ...}."""

    focus: dict[str, Any]
    title: str
    mesh_vertices: np.ndarray | None = None
    mesh_faces: np.ndarray | None = None
    polylines: tuple[Polyline, ...] = ()
    probes: tuple[ProbeSet, ...] = ()
    toolpaths: tuple[Toolpath, ...] = ()
    layers: tuple[LayerStack, ...] = ()
    axes: tuple[AxisGlyphs, ...] = ()
    heights: tuple[HeightStack, ...] = ()
    surfaces: tuple[SurfaceMesh, ...] = ()
    plots: tuple[DeviationPlot, ...] = ()
    scalar_surfaces: tuple[ScalarSurface, ...] = ()
    residuals: tuple[ResidualMap, ...] = ()
    previews: tuple[ProgramPreview, ...] = ()  # slicer-style program previews (move types, layer slider)
    part_matrix: np.ndarray | None = None  # 4 x 4: the part drawn moved into the program's frame
    notes: tuple[str, ...] = field(default_factory=tuple)

    def bounds(self, include_part: bool = True) -> np.ndarray | None:
        """(2, 3) min/max corner of everything in the scene (mm), or None when empty; with
        ``include_part=False`` of what is shown on the part only (traces, probes, programs...)."""
        chunks = [self.mesh_vertices] if (self.mesh_vertices is not None and include_part) else []
        chunks += [p.points for p in self.polylines]
        chunks += [a for p in self.probes for a in (p.planned, p.measured) if a is not None]
        chunks += [t.segments.ends for t in self.toolpaths]
        chunks += [s.vertices for s in self.surfaces]
        chunks += [s.vertices for s in self.scalar_surfaces]
        chunks += [a.positions for a in self.axes]
        chunks += [r.points for r in self.residuals]
        chunks += [p.drawn_points() for p in self.previews]
        for h in self.heights:
            _k, rows, cols = h.heights.shape
            x0, y0 = h.origin_xy
            chunks.append(np.array([[x0, y0, 0.0],
                                    [x0 + cols * h.pitch_mm, y0 + rows * h.pitch_mm, float(np.nanmax(h.heights))]]))
        chunks = [np.asarray(c, dtype=float).reshape(-1, 3) for c in chunks if c is not None and np.size(c)]
        if not chunks:
            return None
        allpts = np.concatenate(chunks)
        allpts = allpts[np.all(np.isfinite(allpts), axis=1)]
        if not len(allpts):
            return None
        return np.stack([allpts.min(axis=0), allpts.max(axis=0)])
