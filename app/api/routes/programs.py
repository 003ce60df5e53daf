"""Programs: G-code that users bring, stored as blobs with their command digest."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Request, Response, UploadFile
from sqlalchemy import func
from sqlmodel import col, select

from app.api import idempotency
from app.api.deps import Limit, Offset, Operator, RuntimeDep, SessionDep, Viewer
from app.api.downloads import attachment
from app.api.machine_schemas import ProgramOut
from app.api.schemas import Page
from app.jobs.gcode_meta import ProgramScan
from app.platform.lookup import get_or_404
from app.platform.models import Program, new_id, utcnow

router = APIRouter(prefix="/api/v1/programs", tags=["programs"])
#: an upload is read, checked and hashed this many bytes at a time (its memory, whatever its lines)
CHUNK_BYTES = 2**20


@router.post("", status_code=201, dependencies=[Operator])
def upload_program(runtime: RuntimeDep, session: SessionDep, request: Request, response: Response,
                   file: Annotated[UploadFile, File(description="G-code text")],
                   idempotency_key: idempotency.IdempotencyKey = None) -> ProgramOut:
    """Upload a G-code program (422 if it is not G-code text).  Read as a stream: checked,
    digested and bounded one MiB at a time, then copied to the blob store."""
    scan = ProgramScan(field="file")
    file.file.seek(0)
    while block := file.file.read(CHUNK_BYTES):
        scan.feed(block)
    meta = scan.result()
    claim = idempotency.claim(request, idempotency_key, bytes.fromhex(meta["sha256"]), file.filename or "")
    replayed = idempotency.replay(session, claim)
    if replayed is not None:
        return replayed  # type: ignore[return-value]
    sha = runtime.blobs.put_file(session, file.file)
    program = Program(id=new_id("prog"), name=(file.filename or "program.gcode").rsplit("/", 1)[-1], sha256=sha,
                      lines=meta["lines"], commands=meta["commands"], commands_sha256=meta["commands_sha256"],
                      bounds=meta["bounds"], created_at=utcnow())
    session.add(program)
    out = ProgramOut(**program.model_dump())
    location = f"/api/v1/programs/{program.id}"
    idempotency.remember(session, claim, 201, out, location=location)
    response.headers["Location"] = location
    return idempotency.commit(session, claim) or out  # type: ignore[return-value]


@router.get("", dependencies=[Viewer])
def list_programs(session: SessionDep, limit: Limit = 100, offset: Offset = 0) -> Page[ProgramOut]:
    total = session.exec(select(func.count()).select_from(Program)).one()
    rows = session.exec(select(Program).order_by(col(Program.created_at).desc()).offset(offset).limit(limit)).all()
    return Page(items=[ProgramOut(**r.model_dump()) for r in rows], total=total)


@router.get("/{program_id}", dependencies=[Viewer])
def get_program(program_id: str, session: SessionDep) -> ProgramOut:
    return ProgramOut(**get_or_404(session, Program, program_id).model_dump())


@router.get("/{program_id}/file", dependencies=[Viewer], responses={200: {"content": {"text/x-gcode": {}}}})
def download_program(program_id: str, runtime: RuntimeDep, session: SessionDep) -> Response:
    program = get_or_404(session, Program, program_id)
    return Response(runtime.blobs.read(program.sha256), media_type="text/x-gcode",
                    headers={"Content-Disposition": attachment(program.name)})
