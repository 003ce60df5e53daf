"""A job's artifacts: files stored content-addressed and listed under the job by name."""

from __future__ import annotations

from typing import Any

from sqlmodel import Session, col

from app.platform.blobs import BlobStore
from app.platform.models import Artifact, utcnow


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
    existing = session.query(Artifact).filter(col(Artifact.job_id) == job_id, col(Artifact.name) == name).one_or_none()
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
