"""Draw a :class:`FocusScene` into a viser server and record every node in the registry.

Batching rules (FIELD_NOTES, viser): toolpaths go into few ``add_line_segments`` nodes
(one per role and move type, split only above ``max_segments_per_node``) with
screen-unit thickness; point clouds are float32 (float16 is 0.125 mm coarse near
200 mm); layer stacks and height maps are one "all" node plus one "current" node that a
slider replaces, never one node per layer.
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from app.viewer import preview_draw
from app.viewer.colors import PALETTE, Palette, deviation_colors, height_colors
from app.viewer.deviation_map import scene_legends, signed_limit_mm
from app.viewer.layer_preview import ProgramPreview
from app.viewer.registry import NodeInfo, SceneRegistry
from app.viewer.scene_data import FocusScene, HeightStack, LayerStack, ScalarSurface, Toolpath

ROOT = "/focus"
PREVIEW_PART_OPACITY = 0.15  # the part over a program preview: the moves inside it keep their colours


@dataclass(frozen=True)
class DrawParams:
    """Sizes of drawn things: thickness in screen pixels, point size and glyph length in mm
    (as fractions of the scene diagonal when the ``*_frac`` variants apply)."""

    line_px: float = 2.0
    toolpath_px: float = 1.5
    point_size_frac: float = 0.008
    max_segments_per_node: int = 500_000
    max_axis_glyphs: int = 400
    max_height_cells: int = 256


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "item"


def polyline_segments(points: np.ndarray) -> np.ndarray:
    """(k, 3) polyline -> (k-1, 2, 3) float32 segments."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    return np.stack([p[:-1], p[1:]], axis=1)


def height_surface(heights: np.ndarray, pitch_mm: float, origin_xy: tuple[float, float],
                   lo: float, hi: float) -> trimesh.Trimesh:
    """A (L, W) height map (mm) as a vertex-coloured triangle grid: cell centres at
    origin + (col + 0.5, row + 0.5) * pitch; NaN heights are drawn at zero."""
    h = np.nan_to_num(np.asarray(heights, dtype=float), nan=0.0)
    rows, cols = h.shape
    ys, xs = np.meshgrid((np.arange(rows) + 0.5) * pitch_mm + origin_xy[1],
                         (np.arange(cols) + 0.5) * pitch_mm + origin_xy[0], indexing="ij")
    vertices = np.column_stack([xs.ravel(), ys.ravel(), h.ravel()])
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    colors = np.column_stack([height_colors(h.ravel(), lo, hi), np.full(rows * cols, 255, np.uint8)])
    return trimesh.Trimesh(vertices, faces, vertex_colors=colors, process=False)


def scalar_surface_mesh(surface: ScalarSurface, signed_limit_mm: float) -> trimesh.Trimesh:
    """A value-per-vertex surface as a vertex-coloured mesh: signed values on the diverging
    scale symmetric about 0 up to ``signed_limit_mm``, others on the ramp from lo to hi."""
    rgb = (deviation_colors(surface.values, signed_limit_mm) if surface.signed
           else height_colors(surface.values, surface.lo, surface.hi))
    colors = np.column_stack([rgb, np.full(len(surface.values), 255, np.uint8)])
    return trimesh.Trimesh(np.asarray(surface.vertices, float), np.asarray(surface.faces, np.int64),
                           vertex_colors=colors, process=False)


class SceneBuilder:
    """Owns the nodes under ``/focus``: draws a scene, swaps slider layers, toggles groups."""

    def __init__(self, server: Any, registry: SceneRegistry, palette: Palette = PALETTE,
                 params: DrawParams = DrawParams()) -> None:
        self.server = server
        self.registry = registry
        self.palette = palette
        self.params = params
        self._handles: dict[str, tuple[str, Any]] = {}  # name -> (group, handle)
        self._layers: dict[str, LayerStack] = {}
        self._heights: dict[str, HeightStack] = {}
        self._height_range: dict[str, tuple[float, float]] = {}
        self._previews: dict[str, ProgramPreview] = {}
        self._point_size = 0.5
        self._signed_limit = 0.0  # mm: the symmetric scale shared by the scene's signed values
        self._lock = threading.RLock()

    # bookkeeping -------------------------------------------------------------------
    def _add(self, name: str, group: str, handle: Any, kind: str, count: int, **meta: Any) -> None:
        handle.visible = self.registry.group_visible(group)
        self._handles[name] = (group, handle)
        self.registry.add_node(name, NodeInfo(kind, group, int(count), meta))

    def _remove(self, name: str) -> None:
        entry = self._handles.pop(name, None)
        if entry is not None:
            entry[1].remove()
        self.registry.remove_node(name)

    def clear(self) -> None:
        with self._lock:
            for name in list(self._handles):
                self._remove(name)
            self._layers.clear()
            self._heights.clear()
            self._previews.clear()

    # what preview_draw uses --------------------------------------------------------------
    def node_names(self) -> list[str]:
        return list(self._handles)

    def add_node(self, name: str, group: str, handle: Any, kind: str, count: int, **meta: Any) -> None:
        self._add(name, group, handle, kind, count, **meta)

    def remove_node(self, name: str) -> None:
        self._remove(name)

    def handle(self, name: str) -> Any:
        """The drawn node ``name`` (None when it is not drawn)."""
        entry = self._handles.get(name)
        return None if entry is None else entry[1]

    @property
    def point_size(self) -> float:
        return self._point_size

    @property
    def previews(self) -> dict[str, ProgramPreview]:
        return dict(self._previews)

    def show_preview_layer(self, name: str, index: int) -> int:
        """Draw program preview ``name`` up to layer position ``index`` (clipped), nothing above."""
        with self._lock:
            return preview_draw.draw_layers(self, self._previews[name], index)

    def show_head(self, position_mm: Any, line: int | None = None) -> None:
        """Draw a machine's head at ``position_mm`` (3,) mm in the scene's frame."""
        with self._lock:
            preview_draw.draw_head(self, np.asarray(position_mm, float).reshape(3), line)

    def set_group_visible(self, group: str, visible: bool) -> None:
        with self._lock:
            self.registry.set_group_visible(group, visible)
            for g, handle in self._handles.values():
                if g == group:
                    handle.visible = visible

    @property
    def layer_stacks(self) -> dict[str, LayerStack]:
        return dict(self._layers)

    @property
    def height_stacks(self) -> dict[str, HeightStack]:
        return dict(self._heights)

    # drawing -----------------------------------------------------------------------
    def draw(self, scene: FocusScene) -> None:
        """Replace the current nodes with ``scene``'s (registry reset by the caller)."""
        with self._lock:
            self.clear()
            bounds = scene.bounds()
            diag = float(np.linalg.norm(bounds[1] - bounds[0])) if bounds is not None else 100.0
            self._point_size = max(diag * self.params.point_size_frac, 0.05)
            self._signed_limit = signed_limit_mm(scene)
            self.registry.set_legends([legend.to_dict() for legend in scene_legends(scene)])
            scn = self.server.scene
            if scene.mesh_vertices is not None and scene.mesh_faces is not None:
                # opaque: a translucent part showed its bottom face's triangle fan through the top;
                # but a program preview's layers lie inside the part, so there it is a faint glass
                opacity = PREVIEW_PART_OPACITY if scene.previews else 1.0
                handle = scn.add_mesh_simple(f"{ROOT}/part", np.asarray(scene.mesh_vertices, np.float32),
                                             np.asarray(scene.mesh_faces, np.uint32), color=self.palette.mesh,
                                             opacity=opacity, side="double", flat_shading=False)
                self._add(f"{ROOT}/part", "part", handle, "mesh", len(scene.mesh_faces), opacity=opacity)
            for line in scene.polylines:
                self._polyline(line.name, line.points, line.role)
            for probes in scene.probes:
                self._probes(probes)
            for toolpath in scene.toolpaths:
                self._toolpath(toolpath)
            for surface in scene.surfaces:
                name = f"{ROOT}/surfaces/{_slug(surface.name)}"
                handle = scn.add_mesh_simple(name, np.asarray(surface.vertices, np.float32),
                                             np.asarray(surface.faces, np.uint32), color=self.palette.compensated,
                                             opacity=0.6, side="double")
                self._add(name, "surfaces", handle, "mesh", len(surface.faces))
            for scalar in scene.scalar_surfaces:
                self._scalar_surface(scalar)
            for residuals in scene.residuals:
                self._residuals(residuals)
            for glyphs in scene.axes:
                self._axes(glyphs)
            for stack in scene.layers:
                self._layer_stack(stack)
            for heights in scene.heights:
                self._height_stack(heights)
            for preview in scene.previews:
                self._previews[preview.name] = preview
                preview_draw.draw_layers(self, preview, len(preview.layers) - 1)

    def _polyline(self, label: str, points: np.ndarray, role: str) -> None:
        group = "curves" if role == "reconstructed" else "traces"
        color = {"reconstructed": self.palette.reconstructed,
                 "flagged": self.palette.dispense}.get(role, self.palette.nominal)
        name = f"{ROOT}/{group}/{_slug(label)}"
        segs = polyline_segments(points)
        if not len(segs):
            return
        handle = self.server.scene.add_line_segments(name, segs, color, thickness=self.params.line_px * 1.5,
                                                     thickness_units="screen")
        self._add(name, group, handle, "segments", len(segs), role=role)

    def _probes(self, probes: Any) -> None:
        size = self._point_size
        if probes.planned is not None and len(probes.planned):
            name = f"{ROOT}/probes/{_slug(probes.name)}/planned"
            pts = np.asarray(probes.planned, np.float32)
            handle = self.server.scene.add_point_cloud(name, pts, self.palette.planned, point_size=size,
                                                       point_shape="diamond", precision="float32")
            self._add(name, "probes", handle, "points", len(pts), role="planned")
        if probes.measured is not None and len(probes.measured):
            name = f"{ROOT}/probes/{_slug(probes.name)}/measured"
            pts = np.asarray(probes.measured, np.float32)
            dev = np.zeros(len(pts)) if probes.deviation_mm is None else np.asarray(probes.deviation_mm, float)
            limit = self._signed_limit
            handle = self.server.scene.add_point_cloud(name, pts, deviation_colors(dev, limit), point_size=size * 1.3,
                                                       point_shape="circle", precision="float32")
            self._add(name, "probes", handle, "points", len(pts), role="measured", deviation_limit_mm=limit)

    def _residuals(self, residuals: Any) -> None:
        """Verification points coloured by residual on their own scale (its legend), the flagged
        ones ringed in the dispense colour."""
        if not len(residuals.points):
            return
        name = f"{ROOT}/residuals/{_slug(residuals.name)}"
        pts = np.asarray(residuals.points, np.float32)
        values = np.asarray(residuals.residual_mm, float)
        limit = float(np.abs(values).max())
        handle = self.server.scene.add_point_cloud(name, pts, deviation_colors(values, limit),
                                                   point_size=self._point_size * 1.8, point_shape="circle",
                                                   precision="float32")
        self._add(name, "residuals", handle, "points", len(pts), role="residual", deviation_limit_mm=limit)
        flagged = np.asarray(residuals.flagged, bool)
        if flagged.any():
            ring = f"{name}/flagged"
            handle = self.server.scene.add_point_cloud(ring, pts[flagged], self.palette.dispense,
                                                       point_size=self._point_size * 3.0, point_shape="square",
                                                       precision="float32")
            self._add(ring, "residuals", handle, "points", int(flagged.sum()), role="flagged")

    def _toolpath(self, toolpath: Toolpath) -> None:
        seg = toolpath.segments
        both = np.stack([seg.starts, seg.ends], axis=1).astype(np.float32)
        colors = {"dispense": self.palette.compensated if toolpath.role == "compensated" else self.palette.dispense,
                  "travel": self.palette.travel}
        errors = toolpath.standoff_error_mm
        for move, mask in (("dispense", seg.dispense), ("travel", ~seg.dispense)):
            chosen = both[mask]
            per_move = None
            if move == "dispense" and errors is not None:  # coloured by standoff error, on the scene's scale
                values = np.asarray(errors, float)[mask]
                per_move = np.repeat(deviation_colors(np.nan_to_num(values, nan=0.0), self._signed_limit)[:, None],
                                     2, 1)
            step = self.params.max_segments_per_node
            for part, start in enumerate(range(0, len(chosen), step)):
                suffix = "" if len(chosen) <= step else f"_{part}"
                name = f"{ROOT}/toolpaths/{_slug(toolpath.name)}/{move}{suffix}"
                chunk = chosen[start:start + step]
                color = colors[move] if per_move is None else per_move[start:start + step]
                width = self.params.toolpath_px * (1.0 if move == "dispense" else 0.6)
                if per_move is not None:  # the nominal program wider: its error colours frame the compensated line
                    width = self.params.toolpath_px * (3.5 if toolpath.role == "nominal" else 1.6)
                if toolpath.role == "warning":  # over the traces' lines (line_px * 1.5), visibly wider
                    width = self.params.line_px * 2.5
                handle = self.server.scene.add_line_segments(name, chunk, color, thickness=width,
                                                             thickness_units="screen")
                meta = {} if per_move is None else {"colored_by": "standoff_error",
                                                    "signed_limit_mm": self._signed_limit}
                self._add(name, "toolpaths", handle, "segments", len(chunk), role=toolpath.role, move=move, **meta)

    def _axes(self, glyphs: Any) -> None:
        pos = np.asarray(glyphs.positions, float)
        dirs = np.asarray(glyphs.directions, float)
        if not len(pos):
            return
        keep = np.unique(np.linspace(0, len(pos) - 1, min(len(pos), self.params.max_axis_glyphs)).round().astype(int))
        starts = pos[keep]
        ends = starts + glyphs.length_mm * dirs[keep]
        name = f"{ROOT}/axes/{_slug(glyphs.name)}"
        handle = self.server.scene.add_line_segments(name, np.stack([starts, ends], axis=1).astype(np.float32),
                                                     self.palette.tool_axis, thickness=self.params.line_px,
                                                     thickness_units="screen")
        self._add(name, "axes", handle, "segments", len(keep))
        tips = self.server.scene.add_point_cloud(f"{name}_tips", ends.astype(np.float32), self.palette.tool_axis,
                                                 point_size=self._point_size * 0.8, precision="float32")
        self._add(f"{name}_tips", "axes", tips, "points", len(keep))

    def _layer_stack(self, stack: LayerStack) -> None:
        self._layers[stack.name] = stack
        nonempty = [s for s in stack.segments if len(s)]
        if nonempty:
            everything = np.concatenate(nonempty).astype(np.float32)
            name = f"{ROOT}/layers/{_slug(stack.name)}/all"
            handle = self.server.scene.add_line_segments(name, everything, self.palette.layers,
                                                         thickness=self.params.line_px * 0.5, thickness_units="screen")
            self._add(name, "layers", handle, "segments", len(everything), layers=len(stack.segments))
        self.show_layer(stack.name, len(stack.segments) - 1)

    def show_layer(self, stack_name: str, index: int) -> int:
        """Draw layer ``index`` (clipped) of a stack as its "current" node; returns the index."""
        with self._lock:
            stack = self._layers[stack_name]
            index = int(np.clip(index, 0, len(stack.segments) - 1))
            name = f"{ROOT}/layers/{_slug(stack.name)}/current"
            self._remove(name)
            segs = np.asarray(stack.segments[index], np.float32).reshape(-1, 2, 3)
            if len(segs):
                handle = self.server.scene.add_line_segments(name, segs, self.palette.current_layer,
                                                             thickness=self.params.line_px * 1.5,
                                                             thickness_units="screen")
                self._add(name, "layers", handle, "segments", len(segs), layer=index, label=stack.labels[index])
            return index

    def _scalar_surface(self, surface: ScalarSurface) -> None:
        """A surface coloured by its per-vertex values (the field's posterior sd map)."""
        name = f"{ROOT}/fields/{_slug(surface.name)}"
        mesh = scalar_surface_mesh(surface, self._signed_limit)
        handle = self.server.scene.add_mesh_trimesh(name, mesh)
        self._add(name, "deviation" if surface.signed else "surfaces", handle, "surface", len(mesh.faces),
                  value_range=[surface.lo, surface.hi], unit=surface.unit, signed=surface.signed)

    def _height_stack(self, stack: HeightStack) -> None:
        cells = self.params.max_height_cells
        k, rows, cols = stack.heights.shape
        step = max(1, int(np.ceil(max(rows, cols) / cells)))
        reduced = HeightStack(stack.name, np.asarray(stack.heights[:, ::step, ::step], float), stack.pitch_mm * step,
                              stack.labels, stack.origin_xy)
        finite = reduced.heights[np.isfinite(reduced.heights)]
        self._height_range[stack.name] = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        self._heights[stack.name] = reduced
        self.show_height(stack.name, k - 1)

    def show_height(self, stack_name: str, index: int) -> int:
        """Draw snapshot ``index`` (clipped) of a height stack as a coloured surface."""
        with self._lock:
            stack = self._heights[stack_name]
            index = int(np.clip(index, 0, len(stack.heights) - 1))
            name = f"{ROOT}/heights/{_slug(stack.name)}"
            self._remove(name)
            lo, hi = self._height_range[stack_name]
            mesh = height_surface(stack.heights[index], stack.pitch_mm, stack.origin_xy, lo, hi)
            handle = self.server.scene.add_mesh_trimesh(name, mesh)
            self._add(name, "heights", handle, "surface", len(mesh.faces), layer=index, label=stack.labels[index],
                      height_range_mm=[lo, hi])
            return index
