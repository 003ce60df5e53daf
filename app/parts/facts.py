"""Facts about a triangle mesh for the part record (pure): edge use, bodies, volume, area.

Edge use comes from one integer sort of the 3F edges (watertight: every edge used twice;
consistent: the two uses run in opposite directions); bodies are connected through shared
edges; volume and area are summed in chunks, so memory stays a few arrays of 3F integers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


@dataclass(frozen=True)
class MeshSummary:
    """Facts about a mesh, in mm.  ``watertight``: every edge shared by exactly two faces
    *and* the winding consistent; ``volume_mm3``: only when it means something (watertight
    and no body inside out), else None; ``bodies``: connected shells."""

    faces: int
    vertices: int
    bounds: list[list[float]]
    watertight: bool
    volume_mm3: float | None
    area_mm2: float
    bodies: int = 1
    notes: tuple[str, ...] = ()
    defects: dict | None = None


@dataclass(frozen=True)
class EdgeFacts:
    """``watertight``: every edge used by exactly two faces; ``consistent``: those two
    faces traverse it in opposite directions; ``labels`` (F,) body of each face (bodies
    are connected through shared edges); ``bodies``: their count."""

    watertight: bool
    consistent: bool
    labels: np.ndarray
    bodies: int
    open_edges: int = 0
    non_manifold_edges: int = 0


def edge_facts(faces: np.ndarray, n_vertices: int) -> EdgeFacts:
    """Edge use of a triangle mesh from one integer sort of its 3F edges (memory: a few
    8-byte arrays of 3F)."""
    f = np.ascontiguousarray(faces, dtype=np.int64)
    a = f.ravel()
    b = np.roll(f, -1, axis=1).ravel()
    forward = a < b
    key = np.minimum(a, b)
    key *= n_vertices
    key += np.maximum(a, b)
    del b
    order = np.argsort(key)
    sorted_key = key[order]
    del key
    starts = np.flatnonzero(np.concatenate([[True], sorted_key[1:] != sorted_key[:-1]]))
    del sorted_key
    runs = np.diff(np.append(starts, len(order)))
    watertight = bool(np.all(runs == 2))
    pair_at = starts[runs == 2]
    e0, e1 = order[pair_at], order[pair_at + 1]
    consistent = watertight and bool(np.all(forward[e0] != forward[e1]))
    del order, forward
    graph = coo_matrix((np.ones(len(e0), dtype=np.int8), (e0 // 3, e1 // 3)), shape=(len(f), len(f)))
    bodies, labels = connected_components(graph, directed=False)
    return EdgeFacts(watertight, consistent, labels, int(bodies), int(np.sum(runs == 1)), int(np.sum(runs > 2)))


def _per_face(mesh: trimesh.Trimesh, chunk: int = 1 << 15) -> tuple[np.ndarray, np.ndarray]:
    """(F,) signed volume contributions (mm^3) and (F,) areas (mm^2), in chunks."""
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    signed, area = np.empty(len(faces)), np.empty(len(faces))
    for i in range(0, len(faces), chunk):
        tri = vertices[faces[i:i + chunk]]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area[i:i + chunk] = 0.5 * np.linalg.norm(cross, axis=1)
        signed[i:i + chunk] = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    return signed, area


def _body_boxes(mesh: trimesh.Trimesh, labels: np.ndarray, bodies: int) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3) lows and highs of each body's vertices."""
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    vertex_body = np.empty(len(vertices), dtype=np.int64)
    vertex_body[faces.ravel()] = np.repeat(labels, 3)
    order = np.argsort(vertex_body, kind="stable")
    starts = np.searchsorted(vertex_body[order], np.arange(bodies))
    return (np.minimum.reduceat(vertices[order], starts, axis=0),
            np.maximum.reduceat(vertices[order], starts, axis=0))


def _volume_if_meaningful(mesh: trimesh.Trimesh, facts: EdgeFacts,
                          signed: np.ndarray) -> tuple[float | None, list[str]]:
    """(volume or None, notes): a volume is reported only for a closed, consistently wound
    mesh whose inside-out bodies (if any) lie inside an outward one (a cavity)."""
    if not (facts.watertight and facts.consistent):
        return None, ["volume not reported: the mesh is not closed with consistent winding (slicing with "
                      "repair: true fixes what it can)"]
    per_body = np.bincount(facts.labels, weights=signed, minlength=facts.bodies)
    if np.any(per_body <= 0):
        lows, highs = _body_boxes(mesh, facts.labels, facts.bodies)
        for b in np.flatnonzero(per_body <= 0):
            inside = [o for o in np.flatnonzero(per_body > 0)
                      if np.all(lows[o] <= lows[b]) and np.all(highs[b] <= highs[o])]
            if not inside:
                return None, [f"volume not reported: body {int(b)} of {facts.bodies} is inside out "
                              f"(slicing with repair: true turns it outward)"]
    total = float(per_body.sum())
    return (total if total > 0 else None), []


def hole_perimeters(mesh: trimesh.Trimesh) -> list[float] | None:
    """Perimeters (mm) of the mesh's boundary loops; None when an open boundary does not
    close into a loop."""
    vertices = np.asarray(mesh.vertices)
    out = []
    for entity in mesh.outline().entities:
        points = np.asarray(entity.points)
        if len(points) < 4 or points[0] != points[-1]:
            return None
        out.append(float(np.linalg.norm(np.diff(vertices[points], axis=0), axis=1).sum()))
    return out


def _defects(mesh: trimesh.Trimesh, facts: EdgeFacts) -> dict | None:
    """What slicing's repair would face: open and non-manifold edges, holes and the largest."""
    if facts.watertight:
        return None
    holes = hole_perimeters(mesh) if facts.non_manifold_edges == 0 else None
    return {"open_edges": facts.open_edges, "non_manifold_edges": facts.non_manifold_edges,
            "holes": None if holes is None else len(holes),
            "largest_hole_mm": None if not holes else round(max(holes), 6),
            "closable": holes is not None}


def summarize(mesh: trimesh.Trimesh) -> MeshSummary:
    """Facts about ``mesh`` (edge use from one sort; volume and area in chunks)."""
    facts = edge_facts(mesh.faces, len(mesh.vertices))
    signed, area = _per_face(mesh)
    volume, notes = _volume_if_meaningful(mesh, facts, signed)
    vertices = np.asarray(mesh.vertices)
    return MeshSummary(
        faces=int(len(mesh.faces)),
        vertices=int(len(vertices)),
        bounds=[[float(v) for v in vertices.min(axis=0)], [float(v) for v in vertices.max(axis=0)]],
        watertight=facts.watertight and facts.consistent,
        volume_mm3=volume,
        area_mm2=float(area.sum()),
        bodies=facts.bodies,
        notes=tuple(notes),
        defects=_defects(mesh, facts),
    )
