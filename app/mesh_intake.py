"""Turn uploaded bytes into a checked triangle mesh (trimesh), or a precise error.

Guards: empty files, unknown formats, unparsable bytes, zip bombs (3MF is a zip: the
declared uncompressed size and the compression ratio are checked before anything is
inflated), non-finite vertices, zero faces.  ``rtree``/``embreex`` make ray queries fast.
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass

import numpy as np
import trimesh

from app.errors import InvalidInput, TooLarge

FORMATS = ("stl", "obj", "ply", "off", "3mf", "glb")
MAX_ZIP_RATIO = 200.0


class MeshError(InvalidInput):
    """The uploaded mesh cannot be used; the message says why."""


@dataclass(frozen=True)
class MeshSummary:
    """Facts about a mesh, in mm."""

    faces: int
    vertices: int
    bounds: list[list[float]]
    watertight: bool
    volume_mm3: float | None
    area_mm2: float


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


def _check_zip(data: bytes, max_unzipped_bytes: int) -> None:
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except zipfile.BadZipFile:
        raise MeshError("3MF file is not a valid zip archive", field="file") from None
    total = sum(info.file_size for info in archive.infolist())
    packed = max(1, sum(info.compress_size for info in archive.infolist()))
    if total > max_unzipped_bytes:
        raise TooLarge(
            f"3MF archive would inflate to {total} bytes (limit {max_unzipped_bytes})", field="file", value=total
        )
    if total / packed > MAX_ZIP_RATIO and total > 10_000_000:
        raise MeshError(
            f"3MF archive has a compression ratio of {total / packed:.0f}:1, refused as a zip bomb",
            field="file",
            value=round(total / packed),
        )


def _check_stl(data: bytes) -> None:
    """Binary STL must have exactly 84 + 50 * n bytes; ASCII STL must start with 'solid'."""
    head = data[:512].lstrip()
    if head[:5].lower() == b"solid" and b"\0" not in head:
        return
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


def parse_mesh(data: bytes, fmt: str, *, max_unzipped_bytes: int) -> trimesh.Trimesh:
    """Parse ``data`` as ``fmt`` into one triangle mesh (scenes are concatenated)."""
    if not data:
        raise MeshError("the uploaded file is empty", field="file", value=0)
    if fmt == "stl":
        _check_stl(data)
    if fmt in ("3mf", "glb") and data[:2] == b"PK":
        _check_zip(data, max_unzipped_bytes)
    elif fmt == "3mf":
        raise MeshError("3MF file is not a valid zip archive", field="file")
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=fmt, force="mesh", process=False)
    except MemoryError:
        raise TooLarge("the mesh is too large to load", field="file") from None
    except Exception as exc:  # trimesh raises many types for garbage input
        raise MeshError(f"could not parse the file as {fmt.upper()}: {type(exc).__name__}: {exc}"[:300], field="file") from None
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(geometries) if geometries else trimesh.Trimesh()
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"the {fmt.upper()} file holds no triangle mesh", field="file")
    return check_mesh(loaded)


def check_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Refuse meshes with no faces or non-finite vertices; merge duplicate vertices."""
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
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)
    if len(mesh.faces) == 0:
        raise MeshError("the mesh has only degenerate faces", field="file")
    return mesh


def summarize(mesh: trimesh.Trimesh) -> MeshSummary:
    watertight = bool(mesh.is_watertight)
    return MeshSummary(
        faces=int(len(mesh.faces)),
        vertices=int(len(mesh.vertices)),
        bounds=[[float(v) for v in row] for row in mesh.bounds],
        watertight=watertight,
        volume_mm3=float(abs(mesh.volume)) if watertight else None,
        area_mm2=float(mesh.area),
    )


def export_mesh(mesh: trimesh.Trimesh, fmt: str) -> bytes:
    """The mesh as binary STL or GLB bytes."""
    if fmt == "stl":
        return mesh.export(file_type="stl")
    if fmt == "glb":
        return trimesh.Scene(mesh).export(file_type="glb")
    raise MeshError(f"cannot export as {fmt!r}; use stl or glb", field="format", value=fmt)
