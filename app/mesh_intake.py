"""Turn uploaded bytes into a checked triangle mesh in the part's frame, or a precise error.

Guards: empty files, unknown formats, unparsable bytes, zip bombs (3MF members are
inflated with a hard cap on the bytes really produced, :mod:`app.mesh_archive`),
non-finite vertices, zero faces.  Binary STL is read straight from the bytes with numpy
(vertices merged by exact float32 value) so an upload peaks at a few times its size.
:func:`intake` then applies the file's units and orientation (:mod:`app.mesh_frame`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field

import numpy as np
import trimesh

from app.errors import InvalidInput, TooLarge
from app.mesh_archive import inflate_zip, stored_zip, threemf_unit
from app.mesh_frame import PartFrame, declared_units, part_frame, size_warnings

FORMATS = ("stl", "obj", "ply", "off", "3mf", "glb")
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (9,)), ("attr", "<u2")])


class MeshError(InvalidInput):
    """The uploaded mesh cannot be used; the message says why."""


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


@dataclass(frozen=True)
class LoadedMesh:
    """A parsed file: ``mesh`` in the file's coordinates and the units it declares (or None)."""

    mesh: trimesh.Trimesh
    file_units: str | None


@dataclass(frozen=True)
class Intake:
    """An upload in the part's frame: ``mesh`` (mm, +Z up), its ``frame``, ``summary``,
    ``warnings``; ``canonical`` holds PLY bytes of ``mesh`` when it differs from the file."""

    mesh: trimesh.Trimesh
    frame: PartFrame
    summary: MeshSummary
    warnings: list[str] = field(default_factory=list)
    canonical: bytes | None = None


def detect_format(filename: str | None, declared: str | None = None) -> str:
    """The mesh format from an explicit value or the file name's extension."""
    candidate = (declared or "").lower().lstrip(".")
    if not candidate and filename and "." in filename:
        candidate = filename.rsplit(".", 1)[1].lower()
    if candidate not in FORMATS:
        raise MeshError(
            f"unsupported mesh format {candidate or '(none)'!r}; use one of {', '.join(FORMATS)}",
            field="file",
            value=filename,
        )
    return candidate


def _binary_stl(data: bytes) -> trimesh.Trimesh | None:
    """Binary STL -> mesh with vertices merged by exact value; None for ASCII STL.

    Binary STL must have exactly 84 + 50 * n bytes.  Memory: the float32 corners (36 B per
    face) and numpy's unique (about 60 B per face) beside the file's 50 B per face."""
    head = data[:512].lstrip()
    if head[:5].lower() == b"solid" and b"\0" not in head:
        return None
    if len(data) < 84:
        raise MeshError(f"not an STL file: {len(data)} bytes is shorter than a binary STL header", field="file")
    declared = int.from_bytes(data[80:84], "little")
    if len(data) != 84 + 50 * declared:
        raise MeshError(
            f"not a valid binary STL: the header declares {declared} triangles ({84 + 50 * declared} bytes) "
            f"but the file has {len(data)} bytes",
            field="file",
            value=len(data),
        )
    records = np.frombuffer(data, dtype=_STL_RECORD, count=declared, offset=84)
    corners = records["corners"].reshape(-1, 3) + np.float32(0.0)   # a copy; -0.0 becomes 0.0
    del records
    keys = corners.view(np.dtype((np.void, 12))).ravel()
    unique, inverse = np.unique(keys, return_inverse=True)
    del corners, keys
    vertices = unique.view(np.float32).reshape(-1, 3).astype(np.float64)
    faces = inverse.reshape(-1, 3).astype(np.int64)
    del inverse
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)


def read_mesh(data: bytes, fmt: str, *, max_unzipped_bytes: int) -> LoadedMesh:
    """Parse ``data`` as ``fmt`` into one triangle mesh (scenes are concatenated) in the
    file's own coordinates, with the units the file declares."""
    if not data:
        raise MeshError("the uploaded file is empty", field="file", value=0)
    file_units = None
    if fmt == "stl":
        fast = _binary_stl(data)
        if fast is not None:
            return LoadedMesh(check_mesh(fast, merged=True), None)
    if fmt == "3mf":
        if data[:2] != b"PK":
            raise MeshError("3MF file is not a valid zip archive", field="file")
        members = inflate_zip(data, max_unzipped_bytes)
        file_units = threemf_unit(members) or "millimeter"
        data = stored_zip(members)
        del members
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=fmt, force="mesh", process=False)
    except MemoryError:
        raise TooLarge("the mesh is too large to load", field="file") from None
    except Exception as exc:  # trimesh raises many types for garbage input
        raise MeshError(f"could not parse the file as {fmt.upper()}: {type(exc).__name__}: {exc}"[:300],
                        field="file") from None
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(geometries) if geometries else trimesh.Trimesh()
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"the {fmt.upper()} file holds no triangle mesh", field="file")
    return LoadedMesh(check_mesh(loaded), declared_units(fmt, file_units))


def parse_mesh(data: bytes, fmt: str, *, max_unzipped_bytes: int) -> trimesh.Trimesh:
    """The mesh in ``data`` in the file's coordinates (what the mesh cache reads)."""
    return read_mesh(data, fmt, max_unzipped_bytes=max_unzipped_bytes).mesh


def check_mesh(mesh: trimesh.Trimesh, merged: bool = False) -> trimesh.Trimesh:
    """Refuse meshes with no faces or non-finite vertices; merge duplicate vertices (unless
    ``merged``) and drop faces that repeat a vertex."""
    vertices = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces)
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError("the mesh has no faces", field="file", value={"faces": int(len(faces))})
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        index = int(np.flatnonzero(bad)[0])
        raise MeshError(
            f"the mesh has {int(bad.sum())} non-finite vertices (first: vertex {index} = {vertices[index].tolist()})",
            field="file",
            value={"vertex": index},
        )
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError("the mesh has faces that index missing vertices", field="file")
    if not merged:
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)
        faces = np.asarray(mesh.faces)
    distinct = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    if not distinct.any():
        raise MeshError("the mesh has only degenerate faces", field="file")
    if not distinct.all():
        mesh = trimesh.Trimesh(vertices=mesh.vertices, faces=faces[distinct], process=False, validate=False)
    return mesh


def _volume_if_meaningful(mesh: trimesh.Trimesh, watertight: bool) -> tuple[float | None, int, list[str]]:
    """(volume or None, body count, notes): a volume is reported only for a closed,
    consistently wound mesh whose inside-out bodies (if any) lie inside an outward one."""
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    bodies = int(labels.max()) + 1 if len(labels) else 0
    if not watertight:
        return None, bodies, ["volume not reported: the mesh is not closed with consistent winding"]
    tri = mesh.triangles
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    per_body = np.bincount(labels, weights=signed, minlength=bodies)
    order = np.argsort(labels, kind="stable")
    starts = np.searchsorted(labels[order], np.arange(bodies))
    lows = np.minimum.reduceat(tri.min(axis=1)[order], starts, axis=0)
    highs = np.maximum.reduceat(tri.max(axis=1)[order], starts, axis=0)
    for b in np.flatnonzero(per_body <= 0):
        inside = [o for o in np.flatnonzero(per_body > 0)
                  if np.all(lows[o] <= lows[b]) and np.all(highs[b] <= highs[o])]
        if not inside:
            return None, bodies, [f"volume not reported: body {int(b)} of {bodies} is inside out "
                                  f"(slicing with repair: true turns it outward)"]
    total = float(per_body.sum())
    return (total if total > 0 else None), bodies, []


def summarize(mesh: trimesh.Trimesh) -> MeshSummary:
    """Facts about ``mesh``; the mesh's cached derived arrays are dropped afterwards."""
    watertight = bool(mesh.is_watertight) and bool(mesh.is_winding_consistent)
    volume, bodies, notes = _volume_if_meaningful(mesh, watertight)
    summary = MeshSummary(
        faces=int(len(mesh.faces)),
        vertices=int(len(mesh.vertices)),
        bounds=[[float(v) for v in row] for row in mesh.bounds],
        watertight=watertight,
        volume_mm3=volume,
        area_mm2=float(mesh.area),
        bodies=bodies,
        notes=tuple(notes),
    )
    mesh._cache.clear()
    return summary


def ply_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Binary little-endian PLY with float64 vertices (exact for any stored mesh)."""
    vertices = np.ascontiguousarray(mesh.vertices, dtype="<f8")
    faces = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"] = 3
    faces["v"] = mesh.faces
    header = ("ply\nformat binary_little_endian 1.0\ncomment conforma part frame (mm, +Z up)\n"
              f"element vertex {len(vertices)}\nproperty double x\nproperty double y\nproperty double z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    return header.encode("ascii") + vertices.tobytes() + faces.tobytes()


def intake(data: bytes, fmt: str, *, max_unzipped_bytes: int, units: str | None = None, up: str | None = None,
           rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Intake:
    """Parse an upload and bring it into the part's frame (mm, +Z up).

    Raises :class:`MeshError`/:class:`InvalidInput` (422, naming ``file``, ``units``,
    ``up`` or ``rotate_deg``) or :class:`TooLarge` (413)."""
    frame = part_frame(fmt, None, units, up, rotate_deg)   # bad choices refused before parsing
    loaded = read_mesh(data, fmt, max_unzipped_bytes=max_unzipped_bytes)
    frame = part_frame(fmt, loaded.file_units, units, up, rotate_deg)
    mesh = loaded.mesh
    canonical = None
    if not frame.is_identity:
        mesh = trimesh.Trimesh(vertices=(frame.scale * frame.rotation @ np.asarray(mesh.vertices).T).T,
                               faces=mesh.faces, process=False, validate=False)
    if not frame.is_identity or fmt in ("3mf", "glb"):
        canonical = ply_bytes(mesh)
    summary = summarize(mesh)
    extent = np.ptp(np.asarray(summary.bounds), axis=0)
    return Intake(mesh=mesh, frame=frame, summary=summary, warnings=size_warnings(extent, frame) +
                  list(summary.notes), canonical=canonical)


def export_mesh(mesh: trimesh.Trimesh, fmt: str) -> bytes:
    """The mesh as binary STL (mm, +Z up) or GLB (metres, +Y up, as glTF specifies)."""
    if fmt == "stl":
        return mesh.export(file_type="stl")
    if fmt == "glb":
        to_gltf = np.eye(4)
        to_gltf[:3, :3] = 0.001 * np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
        scene_mesh = mesh.copy()
        scene_mesh.apply_transform(to_gltf)
        return trimesh.Scene(scene_mesh).export(file_type="glb")
    raise MeshError(f"cannot export as {fmt!r}; use stl or glb", field="format", value=fmt)
