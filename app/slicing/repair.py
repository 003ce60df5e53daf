"""Mesh repair before slicing (pure): what can be fixed is fixed and reported, the rest named.

:func:`repair_mesh` in order: merge duplicate vertices, drop degenerate and duplicate
faces, refuse edges shared by more than two faces (no closing makes those a solid), fill
every hole whose boundary loop is at most ``max_hole_mm`` long (a fan of triangles from
the loop's centroid), then per body fix the winding (consistent across every edge) and
turn inside-out bodies outward (trimesh.repair).  Overlapping shells are united later by
manifold3d (:func:`app.slicing.mesh_prep.prepare_mesh`).  Each change is one line of
``RepairReport.changes``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import trimesh

from app.slicing.errors import MeshError


@dataclass(frozen=True)
class RepairReport:
    """The repaired mesh and one human-readable line per change."""

    mesh: trimesh.Trimesh
    changes: tuple[str, ...]


def _edge_use(mesh: trimesh.Trimesh) -> tuple[int, int]:
    """(edges used once, edges used more than twice)."""
    if len(mesh.faces) == 0:
        return 0, 0
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    return int(np.sum(counts == 1)), int(np.sum(counts > 2))


def _boundary_loops(mesh: trimesh.Trimesh) -> list[npt.NDArray[np.int64]]:
    """Closed boundary loops as vertex index arrays (first != last)."""
    outline = mesh.outline()
    loops: list[npt.NDArray[np.int64]] = []
    for entity in outline.entities:
        points = np.asarray(entity.points, dtype=np.int64)
        if len(points) < 4 or points[0] != points[-1]:
            raise MeshError("mesh cannot be made watertight: an open boundary does not close into a loop "
                            f"(vertices {points[:4].tolist()}...)", field="mesh", value="open boundary")
        loops.append(points[:-1])
    return loops


def _fill_holes(mesh: trimesh.Trimesh, max_hole_mm: float, changes: list[str]) -> trimesh.Trimesh:
    loops = _boundary_loops(mesh)
    vertices = np.asarray(mesh.vertices)
    lengths = [float(np.linalg.norm(vertices[np.roll(loop, -1)] - vertices[loop], axis=1).sum()) for loop in loops]
    too_big = [(length, k) for k, length in enumerate(lengths) if length > max_hole_mm]
    if too_big:
        length, k = max(too_big)
        raise MeshError(f"mesh cannot be made watertight: {len(too_big)} of its {len(loops)} holes are larger than "
                        f"max_hole_mm = {max_hole_mm:.4g} mm (the largest is {length:.4g} mm around, "
                        f"{len(loops[k])} edges near {np.round(vertices[loops[k]].mean(axis=0), 3).tolist()}); "
                        f"close it in CAD or raise max_hole_mm to fill it flat",
                        field="mesh", value={"holes": len(loops), "largest_hole_mm": round(length, 4)})
    new_vertices, new_faces = [vertices], [np.asarray(mesh.faces)]
    next_index = len(vertices)
    for loop in loops:
        if len(loop) == 3:
            new_faces.append(loop[None, ::-1])
            continue
        new_vertices.append(vertices[loop].mean(axis=0)[None])
        fan = np.column_stack([np.full(len(loop), next_index), np.roll(loop, -1), loop])
        new_faces.append(fan)
        next_index += 1
    changes.append(f"filled holes: {len(loops)} ({sum(len(loop) for loop in loops)} open edges, largest "
                   f"{max(lengths):.4g} mm around)")
    return trimesh.Trimesh(vertices=np.vstack(new_vertices), faces=np.vstack(new_faces), process=False)


def repair_mesh(mesh: trimesh.Trimesh, max_hole_mm: float = float("inf")) -> RepairReport:
    """A repaired copy of ``mesh`` and what was changed; :class:`MeshError` (field ``mesh``)
    names what cannot be made watertight."""
    changes: list[str] = []
    m = mesh.copy()
    n_v, n_f = len(m.vertices), len(m.faces)
    m.merge_vertices()
    m.update_faces(m.nondegenerate_faces())
    m.update_faces(m.unique_faces())
    m.remove_unreferenced_vertices()
    if len(m.faces) == 0:
        raise MeshError("mesh has only degenerate faces", field="mesh", value=0)
    if len(m.vertices) != n_v or len(m.faces) != n_f:
        changes.append(f"merged/removed {n_v - len(m.vertices)} vertices and {n_f - len(m.faces)} degenerate "
                       f"or duplicate faces")
    open_edges, shared = _edge_use(m)
    if shared:
        raise MeshError(f"mesh cannot be made watertight: {shared} edges are shared by more than two faces "
                        f"(non-manifold)", field="mesh", value={"non_manifold_edges": shared})
    if open_edges:
        m = _fill_holes(m, max_hole_mm, changes)
    before = m.faces.copy()
    signed_before = m.volume
    trimesh.repair.fix_normals(m, multibody=True)  # type: ignore[no-untyped-call]  # trimesh: unannotated
    same = np.all(np.sort(m.faces, axis=1) == np.sort(before, axis=1), axis=1)
    flipped = int(np.sum(same & ~np.all(m.faces == before, axis=1)))
    if flipped:
        bodies = len(m.split(only_watertight=False))
        changes.append(f"fixed winding and normals: {flipped} of {len(m.faces)} faces flipped "
                       f"({bodies} bodies, each outward); signed volume {signed_before:.6g} -> {m.volume:.6g} mm^3")
    if not m.is_watertight or not m.is_winding_consistent:
        raise MeshError("mesh cannot be made watertight by repair (open or inconsistent edges remain)",
                        field="mesh", value="topology")
    return RepairReport(m, tuple(changes))
