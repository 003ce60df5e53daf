"""Reading and writing stored records, shared by the routers and the job kinds.

Lookups raise :class:`app.errors.NotFound` naming the id; meshes are parsed once per
process and cached by content hash.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any, BinaryIO, TypeVar

import trimesh
from sqlmodel import Session, SQLModel

from app.blobs import BlobStore
from app.errors import ConformaError, NotFound
from app.geometry.slope import SlopePolicy, check_slope
from app.geometry.tolerance import Tolerance
from app.geometry.traces import build_nominal_trace
from app.mesh_intake import intake, parse_mesh
from app.models import Artifact, Job, Machine, Part, Trace, new_id, utcnow

T = TypeVar("T", bound=SQLModel)
_LABELS = {Part: "part", Trace: "trace", Job: "job", Machine: "machine"}


def get_or_404(session: Session, model: type[T], record_id: str, *, field: str | None = None) -> T:
    """The record with ``record_id`` or a NotFound that names it."""
    record = session.get(model, record_id)
    if record is None:
        label = _LABELS.get(model, model.__name__.lower())
        raise NotFound(f"{label} {record_id!r} does not exist", field=field or f"{label}_id", value=record_id)
    return record


class MeshCache:
    """Parsed meshes by sha256 (least recently used first out)."""

    def __init__(self, blobs: BlobStore, capacity: int = 8) -> None:
        self.blobs = blobs
        self.capacity = capacity
        self._items: OrderedDict[str, trimesh.Trimesh] = OrderedDict()
        self._lock = threading.Lock()

    def put(self, sha256: str, mesh: trimesh.Trimesh) -> None:
        with self._lock:
            self._items[sha256] = mesh
            self._items.move_to_end(sha256)
            while len(self._items) > self.capacity:
                self._items.popitem(last=False)

    def mesh(self, part: Part) -> trimesh.Trimesh:
        with self._lock:
            cached = self._items.get(part.sha256)
            if cached is not None:
                self._items.move_to_end(part.sha256)
                return cached
        mesh = parse_mesh(self.blobs.read(part.sha256), part.format, max_unzipped_bytes=2**40)
        self.put(part.sha256, mesh)
        return mesh


def add_artifact(
    session: Session,
    blobs: BlobStore,
    job_id: str,
    name: str,
    data: bytes,
    media_type: str,
    meta: dict[str, Any] | None = None,
) -> Artifact:
    """Store ``data`` content-addressed and list it as artifact ``name`` of ``job_id``."""
    sha = blobs.put(session, data)
    existing = session.query(Artifact).filter(Artifact.job_id == job_id, Artifact.name == name).one_or_none()
    if existing is not None:  # a retried attempt rewrites its artifact
        existing.sha256, existing.bytes, existing.media_type, existing.meta = sha, len(data), media_type, meta or {}
        session.add(existing)
        return existing
    artifact = Artifact(
        job_id=job_id, name=name, media_type=media_type, bytes=len(data), sha256=sha,
        meta=meta or {}, created_at=utcnow(),
    )
    session.add(artifact)
    return artifact


def store_part(session: Session, blobs: BlobStore, meshes: MeshCache, data: bytes | BinaryIO, fmt: str, name: str,
               max_unzipped_bytes: int, units: str | None = None, up: str | None = None,
               rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Part:
    """Parse, check and store an uploaded mesh as a part in mm, +Z up (added to ``session``,
    not committed).  When units or orientation change the file, the converted mesh is
    stored (binary PLY) beside the uploaded file (``source_sha256``).  ``data``: bytes or an
    open binary file (read in chunks where the format allows: binary STL)."""
    taken = intake(data, fmt, max_unzipped_bytes=max_unzipped_bytes, units=units, up=up, rotate_deg=rotate_deg)
    summary = taken.summary
    source = blobs.put(session, data) if isinstance(data, bytes) else blobs.put_file(session, data)
    sha, stored_format = source, fmt
    if taken.canonical is not None:
        sha, stored_format = blobs.put(session, taken.canonical), "ply"
    part = Part(
        id=new_id("part"), name=name, format=stored_format, faces=summary.faces, vertices=summary.vertices,
        bounds=summary.bounds, watertight=summary.watertight, volume_mm3=summary.volume_mm3,
        area_mm2=summary.area_mm2, sha256=sha, created_at=utcnow(), units=taken.frame.units,
        frame=taken.frame.describe(), source_sha256=source, source_format=fmt, warnings=taken.warnings,
        defects=summary.defects,
    )
    session.add(part)
    meshes.put(sha, taken.mesh)
    return part


def build_trace(meshes: MeshCache, part: Part, body: Any, field_prefix: str = "") -> Trace:
    """Drape/snap a trace (an API ``TraceCreate``) onto its part and make the record (not added).

    Errors from the geometry core name their field under ``field_prefix`` (the index of a
    trace in a bulk import)."""
    geometry = body.geometry.model_dump()
    policy = SlopePolicy(warn_deg=min(body.slope_warn_deg, body.slope_max_deg), max_deg=body.slope_max_deg)
    try:
        nominal = build_nominal_trace(meshes.mesh(part), geometry, body.frame, Tolerance())
        slope = check_slope(nominal.points, nominal.normals, policy)
    except ConformaError as exc:
        if field_prefix and exc.field:
            exc.field = f"{field_prefix}.{exc.field}"
        raise
    return Trace(
        id=new_id("trace"), part_id=part.id, name=body.name, frame=body.frame, geometry=geometry,
        standoff_mm=body.standoff_mm, width_mm=body.width_mm, feed_mm_min=body.feed_mm_min,
        length_mm=float(nominal.length_mm), z_min=float(nominal.z_range[0]), z_max=float(nominal.z_range[1]),
        nominal={
            "points": [[round(float(v), 6) for v in p] for p in nominal.points],
            "normals": [[round(float(v), 6) for v in n] for n in nominal.normals],
            "slope_stretch": float(nominal.slope_stretch),
            "slope": slope.to_json(),
        },
        created_at=utcnow(),
    )


def joint_trace_ranges(plan: Job) -> dict[str, tuple[int, int]] | None:
    """{trace id: [first, stop) point indices} of a joint probe plan (``probe_plan`` with
    ``trace_ids``; the same indices hold in its probe runs); None for a one-trace plan."""
    if not (plan.params or {}).get("trace_ids"):
        return None
    return {t["trace_id"]: (t["first"], t["first"] + t["count"]) for t in (plan.result or {}).get("traces", [])}
