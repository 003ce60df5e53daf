"""Turn a triangle mesh into a sliceable solid (check, optionally repair, or refuse).

Checks, in order: non-empty; watertight (every edge shared by exactly two faces) and
consistently wound; positive volume; overlapping shells (self-intersection between
bodies).  With ``repair=True`` the mesh is repaired by :func:`app.slicing.repair.repair_mesh`
(merge duplicate vertices, drop degenerate/duplicate faces, fill holes up to
``max_hole_mm`` around - by default the perimeter of the bounding box's largest face -, fix winding and normals per
body) and overlapping shells are united; every repair is reported; otherwise, or when
repair does not help, :class:`MeshError` names the problem.

Not detected: a *single* shell that passes through itself (a folded surface).  Its
sections are still well defined because manifold3d resolves each slice with the
positive fill rule (the union of the overlapping parts).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import manifold3d
import numpy as np
import numpy.typing as npt
import trimesh

from app.slicing.errors import MeshError
from app.slicing.repair import repair_mesh

#: the parts overlap when their union's volume falls short of their summed volume by more
#: than this relative slack plus :data:`_VOLUME_SLACK_MM3` (mm^3) of round-off
_VOLUME_SLACK_REL = 1e-9
_VOLUME_SLACK_MM3 = 1e-9


@dataclass(frozen=True)
class PreparedMesh:
    """A solid ready to slice.

    ``solid``: manifold3d.Manifold; ``z_min``/``z_max``: mm; ``bounds``: (2, 3) mm;
    ``normals_z``: (F,) z component of unit face normals; ``face_z``: (F, 2) min/max z of
    each face (mm); ``repairs``: human-readable notes of what was repaired;
    ``prism_z``: (B + 1,) sorted distinct vertex heights (mm) and ``prism``: (B,) bool, True
    for a band between two of them that only vertical faces cross (:func:`prism_bands`): the
    section is the same region at every height strictly inside such a band.
    """

    solid: manifold3d.Manifold
    z_min: float
    z_max: float
    bounds: npt.NDArray[np.float64]
    normals_z: npt.NDArray[np.float64]
    face_z: npt.NDArray[np.float64]
    volume: float
    repairs: tuple[str, ...]
    prism_z: npt.NDArray[np.float64] = dataclasses.field(default_factory=lambda: np.zeros(0))
    prism: npt.NDArray[np.bool_] = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=bool))

    def prism_band(self, z: float) -> int | None:
        """The index of the prismatic band ``z`` (mm) lies strictly inside, else None."""
        i = int(np.searchsorted(self.prism_z, z, side="right")) - 1
        if 0 <= i < len(self.prism) and self.prism[i] and self.prism_z[i] < z < self.prism_z[i + 1]:
            return i
        return None


#: a face whose unit normal's z is at most this is vertical: over a 1 m band its section moves
#: by at most 1e-9 mm, a thousandth of the exports' last decimal
VERTICAL_NZ = 1e-12


def prism_bands(vertex_z: npt.NDArray[np.float64], normals_z: npt.NDArray[np.float64],
                face_z: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """The mesh's distinct vertex heights ``(B + 1,)`` mm and, for each band between two
    consecutive ones, whether only vertical faces (``|normals_z|`` <= :data:`VERTICAL_NZ`)
    cross it.  No vertex lies inside a band, so the same faces cross it from bottom to top;
    when they are all vertical, every section inside it is the same region (a prism's walls:
    only the triangulation's diagonals, collinear points on its edges, move with the height).
    ``vertex_z`` (V,) mm; ``normals_z`` (F,); ``face_z`` (F, 2) min/max z of each face, mm."""
    heights = np.unique(vertex_z)
    if len(heights) < 2:
        return heights, np.zeros(0, dtype=bool)
    slanted = np.abs(normals_z) > VERTICAL_NZ
    # the band each slanted face starts in, and the one after its last: +1 and -1 there
    crossed = np.bincount(np.searchsorted(heights, face_z[slanted, 0]), minlength=len(heights))
    crossed -= np.bincount(np.searchsorted(heights, face_z[slanted, 1]), minlength=len(heights))
    return heights, np.cumsum(crossed)[:-1] == 0


def _open_edge_count(mesh: trimesh.Trimesh) -> int:
    edges = mesh.edges_sorted
    if len(edges) == 0:
        return 0
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int(np.sum(counts != 2))


def default_max_hole_mm(mesh_or_bounds: trimesh.Trimesh | npt.NDArray[np.float64]) -> float:
    """The longest hole boundary repair fills by default: the perimeter of the bounding box's
    largest face (plus 1 %) - a hole may be as large as the part's outline, no larger.
    Takes a mesh or its (2, 3) bounds (mm)."""
    bounds = mesh_or_bounds.bounds if isinstance(mesh_or_bounds, trimesh.Trimesh) else mesh_or_bounds
    extents = np.sort(np.ptp(np.asarray(bounds, dtype=float), axis=0))
    return 1.01 * 2.0 * float(extents[1] + extents[2])


def _to_manifold(m: trimesh.Trimesh) -> manifold3d.Manifold:
    return manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(m.vertices, dtype=np.float64),
        tri_verts=np.ascontiguousarray(m.faces, dtype=np.uint64)))


def _diagnose(m: trimesh.Trimesh, repair: bool) -> None:
    """Raise the MeshError that says why ``m`` is not a sliceable solid."""
    open_edges = _open_edge_count(m)
    if open_edges:
        raise MeshError(f"mesh is not watertight: {open_edges} edges are not shared by "
                        f"exactly two faces" + ("" if repair else " (repair disabled)"),
                        field="mesh", value={"open_edges": open_edges})
    if not m.is_winding_consistent:
        raise MeshError("mesh face winding is inconsistent", field="mesh", value="winding")
    if m.volume <= 0:
        raise MeshError(f"mesh encloses a non-positive volume ({m.volume:.6g} mm^3): "
                        f"inside-out", field="mesh", value=float(m.volume))
    raise MeshError("mesh is not an oriented 2-manifold", field="mesh", value="topology")


def prepare_mesh(mesh: trimesh.Trimesh, repair: bool = True, max_hole_mm: float | None = None) -> PreparedMesh:
    """Check (and with ``repair`` fix) ``mesh``; return a :class:`PreparedMesh`.

    Fast path: a mesh that manifold3d accepts as an oriented 2-manifold with positive
    volume is used as is.  Otherwise it is cleaned (``repair``) or refused.
    Raises :class:`MeshError` (field ``"mesh"``) for an empty, open, inconsistently
    wound or inside-out mesh that cannot be (or may not be) repaired.
    """
    if mesh is None or len(mesh.faces) == 0:
        raise MeshError("mesh has no faces", field="mesh", value=0)
    repairs: list[str] = []
    m = mesh
    solid = _to_manifold(m)
    ok = solid.status() == manifold3d.Error.NoError and not solid.is_empty() \
        and solid.volume() > 0
    if not ok:
        if not repair:
            _diagnose(m, repair)
        limit = default_max_hole_mm(mesh) if max_hole_mm is None else max_hole_mm
        report = repair_mesh(mesh, limit)
        m = report.mesh
        repairs.extend(report.changes)
        solid = _to_manifold(m)
        if solid.status() != manifold3d.Error.NoError or solid.is_empty() \
                or solid.volume() <= 0:
            _diagnose(m, repair)
    parts = solid.decompose()
    if len(parts) > 1:
        total = sum(p.volume() for p in parts)
        union = manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add)
        if union.volume() < total * (1 - _VOLUME_SLACK_REL) - _VOLUME_SLACK_MM3:
            if not repair:
                raise MeshError(f"mesh is self-intersecting: {len(parts)} shells overlap "
                                f"by {total - union.volume():.6g} mm^3", field="mesh",
                                value={"shells": len(parts),
                                       "overlap_mm3": float(total - union.volume())})
            repairs.append(f"united {len(parts)} overlapping shells "
                           f"(overlap {total - union.volume():.6g} mm^3)")
            solid = union
    bb = solid.bounding_box()
    bounds = np.array([bb[:3], bb[3:]], dtype=np.float64)
    tri = np.asarray(m.vertices, dtype=np.float64)[np.asarray(m.faces)]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    normals_z = np.divide(normals[:, 2], norm, out=np.zeros(len(norm)), where=norm > 0)
    face_z = np.stack([tri[:, :, 2].min(axis=1), tri[:, :, 2].max(axis=1)], axis=1)
    prism_z, prism = prism_bands(np.asarray(m.vertices, dtype=np.float64)[:, 2], normals_z, face_z)
    return PreparedMesh(solid=solid, z_min=float(bounds[0, 2]), z_max=float(bounds[1, 2]),
                        bounds=bounds, normals_z=normals_z, face_z=face_z,
                        volume=float(solid.volume()), repairs=tuple(repairs), prism_z=prism_z, prism=prism)


def place_on_bed(mesh: trimesh.Trimesh, center_xy: tuple[float, float] = (0.0, 0.0)
                 ) -> trimesh.Trimesh:
    """A copy of ``mesh`` translated so that z_min = 0 and its XY bounding-box centre is at
    ``center_xy`` (mm), as a printer expects."""
    m = mesh.copy()
    lo, hi = m.bounds
    m.apply_translation((center_xy[0] - 0.5 * (lo[0] + hi[0]),
                         center_xy[1] - 0.5 * (lo[1] + hi[1]), -lo[2]))
    return m
