"""The 3-D preview of a circuit import's dry run: the mapped circuit draped on the part.

Built from the dry run's answer (``POST /parts/{id}/circuits:import`` with ``dry_run`` and a
``view_id``) and drawn into that view with :meth:`app.viewer.server.Viewer.show`, before
anything is stored.  What it shows (names under ``/focus``):

* ``part``: the part mesh;
* ``traces/...``: every mapped trace on the part, draped (the nominal path the trace would
  get), blue;
* ``toolpaths/warnings/dispense``: the traces a warning names (stretch above the limit,
  closer than their widths, leaving the part), red, wider than their blue lines under them;
* ``fields/pads``: pads and areas as draped patches coloured by state (0: on the part,
  0.5: an area, 1: off the part or named by a warning);
* ``probes/pad probe rings``: the stations' path inside every pad and area (planned points);
* the notes: the first ``NOTES_SHOWN`` warnings and how many more there are.

Units: mm, part coordinates.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import shapely
import trimesh
from shapely.geometry import Polygon

from app.geometry.drape import top_surface_z
from app.viewer.gcode_paths import ToolpathSegments
from app.viewer.scene_data import FocusScene, Polyline, ProbeSet, ScalarSurface, Toolpath

__all__ = ["circuit_preview_scene"]

NOTES_SHOWN = 20        # warnings listed in the view's notes (a real board has thousands: the console pages them)
LIFT_MM = 0.01          # patches drawn this far above the part so they do not flicker into it
PATCH_CELLS = 40        # a patch's triangles: about 1/40 of its extent across,
PATCH_STEP_MM = (0.5, 2.0)   # but no finer than 0.5 mm (small pads: a few triangles) and no coarser than 2 mm


def _patch(outline: list, mesh: trimesh.Trimesh, holes: list | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """An outline (k, 2) less its holes (each (m, 2)) as a draped triangle patch: vertices (v, 3),
    faces (f, 3); None off the part.  Triangles are about 1/``PATCH_CELLS`` of the patch across,
    within ``PATCH_STEP_MM`` (the outline segmentized, a grid inside), so a large pour follows a
    curved part instead of cutting under it with a few long flat triangles."""
    poly = Polygon(np.asarray(outline, float), [np.asarray(h, float) for h in holes or [] if len(h) >= 3])
    if not poly.is_valid:
        poly = poly.buffer(0)
    if poly.is_empty or poly.area <= 0:
        return None
    x0, y0, x1, y1 = poly.bounds
    step = float(np.clip(max(x1 - x0, y1 - y0) / PATCH_CELLS, *PATCH_STEP_MM))
    gx, gy = np.meshgrid(np.arange(x0 + step / 2, x1, step), np.arange(y0 + step / 2, y1, step))
    inner = shapely.points(np.column_stack([gx.ravel(), gy.ravel()]))
    inner = inner[shapely.contains(poly.buffer(-step / 4), inner)]
    rim = shapely.get_coordinates(shapely.segmentize(poly, step))
    sites = shapely.multipoints(np.vstack([rim, shapely.get_coordinates(inner)]))
    inside = poly.buffer(1e-9)
    tris = [t for t in shapely.get_parts(shapely.delaunay_triangles(sites)) if inside.contains(t.centroid)]
    if not tris:
        return None
    corners = np.array([np.asarray(t.exterior.coords)[:3] for t in tris]).reshape(-1, 2)
    top = top_surface_z(mesh, corners)
    z = np.where(top.hit, top.z, np.nan)
    if not np.isfinite(z).any():
        return None
    z = np.where(np.isfinite(z), z, np.nanmax(z)) + LIFT_MM
    return np.column_stack([corners, z]), np.arange(len(corners)).reshape(-1, 3)


def _warned(warnings: list[dict[str, Any]]) -> set[int]:
    return {int(i) for w in warnings for i in (w.get("traces") or [])}


def circuit_preview_scene(part_id: str, mesh: trimesh.Trimesh, dry_run: dict[str, Any]) -> FocusScene:
    """The preview scene of a dry run (the import endpoint's answer as JSON-like dict)."""
    warned = _warned(dry_run.get("warnings", []))
    lines, red_a, red_b = [], [], []
    for t in dry_run.get("traces", []):
        trace = t.get("trace") or {}
        pts = np.asarray((trace.get("nominal") or {}).get("points") or [], float).reshape(-1, 3)
        if len(pts) < 2:
            continue
        lines.append(Polyline(f"trace {t['index']} {t['name']}"[:120], pts, "nominal"))
        if t["index"] in warned:
            red_a.append(pts[:-1])
            red_b.append(pts[1:])
    toolpaths = []
    if red_a:
        a, b = np.concatenate(red_a), np.concatenate(red_b)
        m = len(a)
        toolpaths.append(Toolpath("warnings", ToolpathSegments(a, b, np.ones(m, bool), np.full(m, -1, np.int64),
                                                               np.zeros(m), np.zeros(m)), "warning"))
    verts, faces, values = [], [], []
    outlines: list[tuple[Any, Any, float]] = [(p["outline_xy_mm"], [], 0.0 if p["on_part"] else 1.0)
                                              for p in dry_run.get("pads", [])]
    outlines += [(a["exterior_xy_mm"], a.get("holes_xy_mm") or [], 0.5) if isinstance(a, dict) else (a, [], 0.5)
                 for a in dry_run.get("areas", [])]
    offset = 0
    for outline, holes, value in outlines:
        patch = _patch(outline, mesh, holes)
        if patch is None:
            continue
        verts.append(patch[0])
        faces.append(patch[1] + offset)
        values.append(np.full(len(patch[0]), value))
        offset += len(patch[0])
    surfaces: tuple[ScalarSurface, ...] = ()
    if verts:
        surfaces = (ScalarSurface("pads", np.concatenate(verts), np.concatenate(faces), np.concatenate(values),
                                  0.0, 1.0, unit="state (0 on the part, 0.5 area, 1 warned)"),)
    rings = [np.asarray(p["points"], float).reshape(-1, 3) for p in dry_run.get("probe_paths", []) if p.get("points")]
    probes = (ProbeSet("pad probe rings", planned=np.concatenate(rings)),) if rings else ()
    warnings = dry_run.get("warnings", [])
    notes = tuple(f"{w.get('kind')}: {w.get('message', '')}"[:200] for w in warnings[:NOTES_SHOWN])
    if len(warnings) > NOTES_SHOWN:
        notes += (f"... and {len(warnings) - NOTES_SHOWN} more warnings "
                  "(the import page lists them all, page by page)",)
    return FocusScene(
        focus={"part_id": part_id, "preview": dry_run.get("import_id")},
        title=f"circuit preview {dry_run.get('import_id')} (dry run, nothing stored)",
        mesh_vertices=np.asarray(mesh.vertices), mesh_faces=np.asarray(mesh.faces),
        polylines=tuple(lines), probes=probes, toolpaths=tuple(toolpaths), scalar_surfaces=surfaces,
        notes=("dry run: nothing is stored until the import is accepted",) + notes)
