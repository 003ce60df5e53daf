"""Storing an uploaded mesh as a part: parsed, checked, converted to mm and +Z up, and
kept content-addressed."""

from __future__ import annotations

from typing import BinaryIO

from sqlmodel import Session

from app.parts.intake import intake
from app.parts.meshes import MeshCache
from app.platform.blobs import BlobStore
from app.platform.models import Part, new_id, utcnow


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
