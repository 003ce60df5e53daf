"""Reading and writing stored records, shared by the routers and the job kinds.

Lookups raise :class:`app.errors.NotFound` naming the id; meshes are parsed once per
process and cached by content hash.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any, TypeVar

import trimesh
from sqlmodel import Session, SQLModel

from app.blobs import BlobStore
from app.errors import NotFound
from app.mesh_intake import parse_mesh
from app.models import Artifact, Job, Machine, Part, Trace, utcnow

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
