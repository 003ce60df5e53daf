"""Parts: upload a mesh, list, read, download, delete."""

from __future__ import annotations

import hashlib
from typing import Annotated, BinaryIO, Literal

from fastapi import APIRouter, File, Form, HTTPException, Query, Request, Response, UploadFile
from sqlalchemy import delete, func
from sqlmodel import col, select

from app.api import idempotency
from app.api.deps import Limit, Offset, Operator, RuntimeDep, SessionDep, Viewer
from app.api.downloads import attachment
from app.api.part_checks import check_part_geometry
from app.api.schemas import Page, PartOut
from app.domain.errors import Conflict, NotFound
from app.parts.frame import Units, Up, parse_angles
from app.parts.intake import detect_format, export_mesh
from app.parts.storage import store_part
from app.platform.db import lock_for_delete
from app.platform.lookup import get_or_404
from app.platform.models import JobReference, Part, Trace

router = APIRouter(prefix="/api/v1/parts", tags=["parts"])


def part_out(part: Part) -> PartOut:
    return PartOut(**part.model_dump())


def _file_sha256(stream: BinaryIO) -> str:
    """sha256 of an uploaded file, read in 1 MiB chunks (the file is rewound after)."""
    digest = hashlib.sha256()
    for chunk in iter(lambda: stream.read(2**20), b""):
        digest.update(chunk)
    stream.seek(0)
    return digest.hexdigest()


@router.post("", status_code=201, dependencies=[Operator])
def upload_part(
    runtime: RuntimeDep,
    session: SessionDep,
    request: Request,
    response: Response,
    file: Annotated[UploadFile, File(description="STL (ascii/binary), OBJ, PLY, OFF, 3MF or GLB")],
    name: Annotated[str | None, Form(max_length=200)] = None,
    format: Annotated[str | None, Form(description="overrides the file extension")] = None,
    units: Annotated[Units | None, Form(
        description="the file's units (default: what the file declares - 3MF unit, GLB metres - else mm)")] = None,
    up: Annotated[Up | None, Form(
        description="the file's axis that points up (default +y for GLB as glTF specifies, else +z)")] = None,
    rotate_deg: Annotated[str | None, Form(
        description='further rotation "rx,ry,rz" in degrees about X, then Y, then Z', max_length=100)] = None,
    idempotency_key: idempotency.IdempotencyKey = None,
) -> PartOut:
    """Upload a part mesh (413 over the size limit; 422 for empty, non-finite, degenerate,
    unbounded or unparsable meshes).

    The stored part is in millimetres with +Z up; ``units``, ``up`` and ``rotate_deg`` say how
    to read the file, and the response's ``frame`` and ``warnings`` say what was done."""
    claim = idempotency.claim(request, idempotency_key, _file_sha256(file.file), file.filename or "", name or "",
                              format or "", units or "", up or "", rotate_deg or "")
    replayed = idempotency.replay(session, claim)
    if replayed is not None:
        return replayed  # type: ignore[return-value]
    fmt = detect_format(file.filename, format)
    part = store_part(session, runtime.blobs, runtime.meshes, file.file, fmt,
                      name or (file.filename or "part").rsplit("/", 1)[-1],
                      max_unzipped_bytes=int(runtime.settings.max_unzipped_mb * 2**20),
                      units=units, up=up, rotate_deg=parse_angles(rotate_deg))
    check_part_geometry(part)
    out = part_out(part)
    location = f"/api/v1/parts/{part.id}"
    idempotency.remember(session, claim, 201, out, location=location)
    response.headers["Location"] = location
    return idempotency.commit(session, claim) or out  # type: ignore[return-value]


@router.get("", dependencies=[Viewer])
def list_parts(session: SessionDep, limit: Limit = 100,
               offset: Offset = 0) -> Page[PartOut]:
    total = session.exec(select(func.count()).select_from(Part)).one()
    rows = session.exec(select(Part).order_by(col(Part.created_at).desc(), col(Part.id))
                        .offset(offset).limit(limit)).all()
    return Page(items=[part_out(p) for p in rows], total=total)


@router.get("/{part_id}", dependencies=[Viewer])
def get_part(part_id: str, session: SessionDep) -> PartOut:
    return part_out(get_or_404(session, Part, part_id))


@router.get("/{part_id}/mesh", dependencies=[Viewer],
            responses={200: {"content": {"model/stl": {}, "model/gltf-binary": {}}}})
def download_mesh(part_id: str, runtime: RuntimeDep, session: SessionDep,
                  format: Annotated[Literal["stl", "glb"], Query()] = "stl") -> Response:
    """The part's mesh as binary STL or GLB."""
    part = get_or_404(session, Part, part_id)
    data = export_mesh(runtime.meshes.mesh(part), format)
    media = "model/stl" if format == "stl" else "model/gltf-binary"
    return Response(data, media_type=media, headers={"Content-Disposition": attachment(f"{part.id}.{format}")})


@router.delete("/{part_id}", status_code=204)
def delete_part(part_id: str, session: SessionDep, role: str = Operator,
                force: Annotated[bool, Query(description="admin only: delete even if jobs reference it")] = False,
                ) -> None:
    """Delete a part and its traces; 409 while jobs reference them unless ``force`` (admin).

    One transaction that first locks the part and its traces, so a job or trace created
    at the same moment either lands before (then this is a 409, or its trace is deleted
    with the part) or finds the part gone (404): never a reference to nothing."""
    if force and role != "admin":
        raise HTTPException(403, "force=true needs the admin role")
    if not lock_for_delete(session, Part, [part_id]):
        session.rollback()
        raise NotFound(f"part {part_id!r} does not exist", field="part_id", value=part_id)
    part = get_or_404(session, Part, part_id)
    trace_ids = list(session.exec(select(Trace.id).where(Trace.part_id == part_id)).all())
    lock_for_delete(session, Trace, trace_ids)
    refs = session.exec(select(col(JobReference.job_id))
                        .where(col(JobReference.ref_id).in_([part_id, *trace_ids]))).all()
    if refs and not force:
        session.rollback()
        raise Conflict(f"part {part_id!r} is referenced by {len(set(refs))} job(s), e.g. {sorted(set(refs))[0]}",
                       field="part_id", value=part_id)
    session.exec(delete(JobReference).where(col(JobReference.ref_id).in_([part_id, *trace_ids])))
    session.exec(delete(Trace).where(col(Trace.part_id) == part_id))
    session.delete(part)
    session.commit()

