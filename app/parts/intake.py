"""Turn uploaded bytes into a checked triangle mesh in the part's frame, or a precise error.

Guards: empty files, unknown formats, unparsable bytes, zip bombs (3MF members are
inflated with a hard cap on the bytes really produced, :mod:`app.parts.archive`),
non-finite vertices, zero faces.  Binary STL is read straight from the bytes with numpy
(vertices merged by exact float32 value) so an upload peaks at a few times its size.
:func:`intake` then applies the file's units and orientation (:mod:`app.parts.frame`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np
import trimesh

from app.domain.errors import InvalidInput, TooLarge
from app.parts.archive import inflate_zip, stored_zip, threemf_unit
from app.parts.facts import MeshSummary, summarize
from app.parts.frame import PartFrame, declared_units, part_frame, size_warnings

FORMATS = ("stl", "obj", "ply", "off", "3mf", "glb")
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (9,)), ("attr", "<u2")])


class MeshError(InvalidInput):
    """The uploaded mesh cannot be used; the message says why."""


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


def _binary_stl(source: bytes | BinaryIO) -> trimesh.Trimesh | None:
    """Binary STL (bytes or an open binary file) -> mesh with vertices merged by exact
    value; None for ASCII STL.

    Binary STL must have exactly 84 + 50 * n bytes.  A file is read in chunks of records
    straight into the float32 corners (36 B per face), so the file itself is never held;
    merging adds about 100 B per face at its peak."""
    handle = io.BytesIO(source) if isinstance(source, (bytes, bytearray, memoryview)) else source
    handle.seek(0, io.SEEK_END)
    size = handle.tell()
    handle.seek(0)
    head = handle.read(512)
    stripped = head.lstrip()
    if stripped[:5].lower() == b"solid" and b"\0" not in stripped:
        return None
    if size < 84:
        raise MeshError(f"not an STL file: {size} bytes is shorter than a binary STL header", field="file")
    declared = int.from_bytes(head[80:84], "little")
    if size != 84 + 50 * declared:
        raise MeshError(
            f"not a valid binary STL: the header declares {declared} triangles ({84 + 50 * declared} bytes) "
            f"but the file has {size} bytes",
            field="file",
            value=size,
        )
    corners = np.empty((declared, 9), dtype=np.float32)
    handle.seek(84)
    step = 1 << 16
    for start in range(0, declared, step):
        count = min(step, declared - start)
        block = np.frombuffer(handle.read(50 * count), dtype=_STL_RECORD, count=count)
        corners[start:start + count] = block["corners"]
    corners = corners.reshape(-1, 3)
    corners += np.float32(0.0)                     # -0.0 becomes 0.0
    vertices, faces = merge_exact(corners)
    del corners
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)


def merge_exact(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3F, 3) float32 triangle corners -> (V, 3) float64 distinct vertices and (F, 3) faces.

    Corners are grouped by a 64-bit mix of their bits (one integer sort instead of a
    12-byte one); the grouping is then verified exactly, and a hash collision (never seen,
    but possible) falls back to numpy's exact unique over the raw bytes."""
    bits = corners.view(np.uint32)
    key = bits[:, 0].astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    for column, (add, mul) in ((1, (0x632BE59BD9B4E019, 0xBF58476D1CE4E5B9)),
                               (2, (0x94D049BB133111EB, 0xD6E8FEB86659FD93))):
        mixed = bits[:, column].astype(np.uint64)
        mixed += np.uint64(add)
        mixed *= np.uint64(mul)
        key ^= mixed
        del mixed
    order = np.argsort(key)
    sorted_key = key[order]
    del key
    first = np.empty(len(order), dtype=bool)
    first[:1] = True
    np.not_equal(sorted_key[1:], sorted_key[:-1], out=first[1:])
    del sorted_key
    group = np.cumsum(first) - 1
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = group
    unique = corners[order[first]]
    del order, first, group
    chunk = 1 << 20
    exact = all(np.array_equal(unique[inverse[i:i + chunk]], corners[i:i + chunk])
                for i in range(0, len(corners), chunk))
    if not exact:                                              # a collision: be exact instead
        keys = corners.view(np.dtype((np.void, 12))).ravel()
        raw, inverse = np.unique(keys, return_inverse=True)
        unique = raw.view(np.float32).reshape(-1, 3)
    return unique.astype(np.float64), inverse.reshape(-1, 3)


def _size(source: bytes | BinaryIO) -> int:
    if isinstance(source, (bytes, bytearray, memoryview)):
        return len(source)
    source.seek(0, io.SEEK_END)
    return source.tell()


def read_mesh(source: bytes | BinaryIO, fmt: str, *, max_unzipped_bytes: int) -> LoadedMesh:
    """Parse ``source`` (bytes or an open binary file) as ``fmt`` into one triangle mesh
    (scenes are concatenated) in the file's own coordinates, with the units the file
    declares.  Binary STL files are read in chunks; other formats are read whole."""
    if _size(source) == 0:
        raise MeshError("the uploaded file is empty", field="file", value=0)
    file_units = None
    if fmt == "stl":
        fast = _binary_stl(source)
        if fast is not None:
            return LoadedMesh(check_mesh(fast, merged=True), None)
    if isinstance(source, (bytes, bytearray, memoryview)):
        data = bytes(source)
    else:
        source.seek(0)
        data = source.read()
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


RAW_COORDINATE_LIMIT = 1e9  # file units, before unit conversion (app.api.part_checks bounds the mm)


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
    worst = float(np.abs(vertices).max())
    if worst > RAW_COORDINATE_LIMIT:  # before merging: at 1e200 every vertex rounds together
        raise MeshError(f"the mesh's coordinates reach {worst:.6g} (file units); they must be within "
                        f"±{RAW_COORDINATE_LIMIT:g} (1 km in µm) — and within ±1e6 mm once in mm",
                        field="file", value=worst)
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


def intake(data: bytes | BinaryIO, fmt: str, *, max_unzipped_bytes: int, units: str | None = None,
           up: str | None = None, rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Intake:
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
        return _exported(mesh.export(file_type="stl"))
    if fmt == "glb":
        to_gltf = np.eye(4)
        to_gltf[:3, :3] = 0.001 * np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
        scene_mesh = mesh.copy()
        scene_mesh.apply_transform(to_gltf)
        return _exported(trimesh.Scene(scene_mesh).export(file_type="glb"))
    raise MeshError(f"cannot export as {fmt!r}; use stl or glb", field="format", value=fmt)


def _exported(data: object) -> bytes:
    """trimesh's export of a binary format (typed as bytes, str or dict) as bytes."""
    if not isinstance(data, bytes):
        raise TypeError(f"trimesh exported {type(data).__name__}, not bytes")
    return data
