"""Laying a placed layout on the part: ``project`` (vertical projection) or ``wrap``
(exponential map at the placement's origin, see :mod:`app.circuits.wrap`).

Both give top-view geometry in the API's form (``frame: "xy"``), so traces are then draped
like any other trace: ``project`` keeps the exact placed curve (a NURBS); ``wrap`` gives the
top view of the wrapped curve as a polyline, sampled every ``step_mm`` of layout length and
at every ``chord_mm`` of layout curvature.  A trace's stretch is its length on the surface
over its layout length (1 for a length-preserving map; for ``project`` the slope stretch).
Warnings: a trace that leaves the part, a stretch beyond ``max_stretch``, and two traces of
different nets closer than their half widths (top view).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import shapely
import trimesh
from shapely import STRtree
from shapely.geometry import LineString

from app.circuits.layout import Layout, LayoutTrace, copper_side
from app.circuits.placement import LayoutPlacement, place_layout
from app.circuits.wrap import SurfaceWalker
from app.geometry.cl_points import cl_points
from app.geometry.drape import top_surface_z

__all__ = ["MappedTrace", "MappedPad", "MappedArea", "MappedLayout", "MappingOptions", "map_layout"]

Mapping = Literal["project", "wrap"]


@dataclass(frozen=True)
class MappingOptions:
    mapping: Mapping = "project"
    max_stretch: float = 1.01
    step_mm: float = 0.25
    chord_mm: float = 0.001


@dataclass
class MappedTrace:
    """geometry: API form (top view); surface_points (k, 3) mm (NaN rows off the part);
    layout_length_mm; length_mm on the surface; stretch = length / layout length."""

    index: int
    source: dict[str, Any]
    geometry: dict[str, Any]
    surface_points: npt.NDArray[np.float64]
    layout_length_mm: float
    length_mm: float
    stretch: float
    on_part: bool
    top_view: npt.NDArray[np.float64]


@dataclass
class MappedPad:
    """center (3,) mm on the surface (NaN off the part); outline_xy (k, 2) mm top view."""

    name: str
    shape: str
    source: dict[str, Any]
    center: npt.NDArray[np.float64]
    outline_xy: npt.NDArray[np.float64]
    on_part: bool


@dataclass
class MappedArea:
    """A filled area (a copper pour) in the top view: exterior (k, 2) mm and its holes (each
    (m, 2) mm), which are not copper: the fill leaves them empty."""

    name: str
    source: dict[str, Any]
    exterior_xy: npt.NDArray[np.float64]
    holes_xy: list[npt.NDArray[np.float64]]


@dataclass
class MappedLayout:
    """``vias``: API dicts (center_mm on the surface, NaN off the part; diameter_mm, drill_mm,
    net, layers); ``outline``: the board's edge rings (k, 2) mm in the top view."""

    traces: list[MappedTrace]
    pads: list[MappedPad]
    areas: list[MappedArea]
    warnings: list[dict[str, Any]] = field(default_factory=list)
    vias: list[dict[str, Any]] = field(default_factory=list)
    outline: list[npt.NDArray[np.float64]] = field(default_factory=list)


def _distinct(points: npt.NDArray[np.float64], min_gap_mm: float = 1e-5) -> npt.NDArray[np.float64]:
    """Drop points closer than ``min_gap_mm`` to their predecessor (the last point is kept)."""
    gap = np.linalg.norm(np.diff(points, axis=0), axis=1)
    keep = np.concatenate([[True], gap > min_gap_mm])
    if not keep[-1]:                       # the end is exact: it replaces its near-duplicate predecessor
        kept = np.flatnonzero(keep)
        keep[-1] = True
        if len(kept) > 1:
            keep[kept[-1]] = False
    kept_points: npt.NDArray[np.float64] = points[keep]
    return kept_points


def _layout_samples(trace: LayoutTrace, opts: MappingOptions) -> npt.NDArray[np.float64]:
    """Layout points (k, 2): the curve's chord-verified CL points plus one every step_mm
    (consecutive points at least 10 nm apart)."""
    return _distinct(_raw_samples(trace, opts))


def _raw_samples(trace: LayoutTrace, opts: MappingOptions) -> npt.NDArray[np.float64]:
    """Layout points (k, 2) before near-duplicates are dropped."""
    curve = trace.curve
    if curve.degree == 1:                          # straight spans: exact at the breakpoints, then every step
        pts = curve.control_points
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        n = np.maximum(1, np.ceil(seg / opts.step_mm)).astype(int)
        parts = [pts[i] + np.linspace(0.0, 1.0, n[i], endpoint=False)[:, None] * (pts[i + 1] - pts[i])
                 for i in range(len(seg)) if seg[i] > 0]
        return np.vstack(parts + [pts[-1:]])
    u_cl = cl_points(curve, opts.chord_mm).u
    n = max(2, int(np.ceil(curve.length / opts.step_mm)) + 1)
    u_step = curve.param_at_length(np.linspace(0.0, curve.length, n))
    u = np.unique(np.concatenate([u_cl, u_step]))
    samples: npt.NDArray[np.float64] = curve.evaluate(u)
    return samples


def _length(points: npt.NDArray[np.float64]) -> float:
    """Polyline length (mm) of points (k, d)."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def _spacing_warnings(traces: list[MappedTrace], widths: list[float], nets: list[str]) -> list[dict[str, Any]]:
    """Pairs of traces of different (or no) nets closer than their half widths, not touching at
    their ends (top view); candidate pairs from one STRtree query, distances vectorised."""
    if len(traces) < 2:
        return []
    lines = np.array([LineString(t.top_view) for t in traces], dtype=object)
    w = np.asarray(widths, float)
    net = np.asarray(nets, dtype=object)
    i, j = STRtree(lines).query(lines, predicate="dwithin", distance=float(w.max(initial=0.0)))
    keep = (j > i) & ((net[i] == "") | (net[i] != net[j]))
    i, j = i[keep], j[keep]
    need = 0.5 * (w[i] + w[j])
    gap = shapely.distance(lines[i], lines[j])
    ends = np.array([[t.top_view[0], t.top_view[-1]] for t in traces])           # (n, 2, 2)
    end_gap = np.linalg.norm(ends[i][:, :, None, :] - ends[j][:, None, :, :], axis=3).min(axis=(1, 2))
    close = (need > 0) & (gap < need) & (end_gap > need)
    return [{"kind": "spacing", "traces": [traces[a].index, traces[b].index], "value": round(float(g), 6),
             "message": f"traces {traces[a].index} and {traces[b].index} are {g:.4f} mm apart, closer than "
                        f"their half widths ({n:.4f} mm)"}
            for a, b, g, n in zip(i[close], j[close], gap[close], need[close])]


def map_layout(layout: Layout, placement: LayoutPlacement, mesh: trimesh.Trimesh,
               opts: MappingOptions = MappingOptions()) -> MappedLayout:
    """Place and map every trace and pad of ``layout`` onto ``mesh``'s upper surface."""
    origin = np.asarray(placement.origin_mm, float)
    placed = place_layout(layout, placement, relative=opts.mapping == "wrap")
    walker = SurfaceWalker(mesh) if opts.mapping == "wrap" else None

    def to_surface(points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Placed points (k, 2) -> surface points (k, 3) (NaN off the part)."""
        if walker is not None:
            return walker.exp_map(origin, points).points
        top = top_surface_z(mesh, points)
        return np.column_stack([points, np.where(top.hit, top.z, np.nan)])

    traces: list[MappedTrace] = []
    warnings: list[dict[str, Any]] = []
    for i, t in enumerate(placed.traces):
        samples = _layout_samples(t, opts)
        surface = to_surface(samples)
        on_part = bool(np.isfinite(surface[:, 2]).all())
        layout_len = float(t.curve.length)
        if opts.mapping == "wrap":
            xy = surface[:, :2] if on_part else samples + origin
            geometry = {"type": "polyline", "points": [[float(a), float(b)] for a, b in xy]}
        else:
            geometry = {"type": "nurbs", **t.curve.to_dict()}
        length = _length(surface) if on_part else float("nan")
        stretch = length / layout_len if on_part else float("nan")
        top_view = surface[:, :2] if on_part else samples + (origin if walker else 0.0)
        traces.append(MappedTrace(i, t.source.to_dict(), geometry, surface, layout_len, length, stretch, on_part,
                                  top_view))
        if not on_part:
            k = int(np.argmax(~np.isfinite(surface[:, 2])))
            warnings.append({"kind": "leaves_part", "traces": [i], "value": [round(float(c), 6) for c in
                                                                            (samples[k] + (origin if walker else 0))],
                             "message": f"trace {i} ({t.source.entity}) leaves the part's upper surface"})
        elif abs(stretch - 1.0) > opts.max_stretch - 1.0:
            warnings.append({"kind": "stretch", "traces": [i], "value": round(stretch, 6),
                             "message": f"trace {i} ({t.source.entity}) is stretched {stretch:.5f}x "
                                        f"(limit {opts.max_stretch})"})
    pads = []
    for p in placed.pads:
        pts = to_surface(np.vstack([p.center[None, :], p.exterior]))
        ok = bool(np.isfinite(pts[:, 2]).all())
        pads.append(MappedPad(p.name, p.shape, p.source.to_dict(), pts[0], pts[1:, :2], ok))
        if not ok:
            warnings.append({"kind": "leaves_part", "pads": [p.name], "value": p.name,
                             "message": f"pad {p.name} is not all on the part's upper surface"})
    areas = [MappedArea(a.source.entity, a.source.to_dict(), to_surface(a.exterior)[:, :2],
                        [to_surface(h)[:, :2] for h in a.holes]) for a in placed.areas]
    widths = [t.source.width_mm for t in placed.traces]
    nets = [t.source.net for t in placed.traces]
    warnings += _spacing_warnings(traces, widths, nets)
    via_points = to_surface(np.array([v.center for v in placed.vias])) if placed.vias else np.zeros((0, 3))
    vias = [{"center_mm": [None if not np.isfinite(c) else round(float(c), 6) for c in p], "diameter_mm": v.diameter_mm,
             "drill_mm": v.drill_mm, "net": v.net, "layers": list(v.layers),
             "sides": [copper_side(name) for name in v.layers], "on_part": bool(np.isfinite(p).all())}
            for v, p in zip(placed.vias, via_points)]
    outline = []
    for r in placed.outline:             # an edge off the part (wrap) stays where the layout puts it
        on = to_surface(r)[:, :2] if walker is not None else r
        outline.append(np.where(np.isfinite(on), on, r + origin))
    warnings += [{"kind": "not_printed", "message": m} for m in layout.skipped]
    return MappedLayout(traces, pads, areas, warnings, vias, outline)
