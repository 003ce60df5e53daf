"""Files: data a user brings for jobs to read (measured height maps, mask images, CMM points).

Jobs reference a file by id (e.g. ``jetting_next_layer``'s ``measured: {file_id}``).
Files are content-addressed blobs like artifacts; the type is checked from the bytes.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Request, Response, UploadFile
from pydantic import BaseModel
from sqlalchemy import func
from sqlmodel import col, select

from app.api import idempotency
from app.api.deps import Limit, Offset, Operator, RuntimeDep, SessionDep, Viewer
from app.api.downloads import attachment
from app.api.schemas import Page, UtcDatetime
from app.domain.errors import InvalidInput
from app.platform.array_files import check_upload
from app.platform.lookup import get_or_404
from app.platform.models import UploadedFile, new_id, utcnow

router = APIRouter(prefix="/api/v1/files", tags=["files"])
# media type by leading bytes; text formats by name
_MAGIC = ((b"\x89PNG\r\n\x1a\n", "image/png"), (b"PK\x03\x04", "application/zip"), (b"\x93NUMPY", "application/x-npy"))
_TEXT = {"csv": "text/csv", "json": "application/json", "txt": "text/plain"}


class FileOut(BaseModel):
    id: str
    name: str
    media_type: str
    bytes: int
    sha256: str
    created_at: UtcDatetime


def media_type_of(name: str, data: bytes) -> str:
    """The file's media type from its leading bytes (binary) or its extension (text)."""
    if not data:
        raise InvalidInput("the uploaded file is empty", field="file", value=0)
    for magic, media in _MAGIC:
        if data.startswith(magic):
            return media
    extension = name.rsplit(".", 1)[-1].lower() if "." in name else ""
    if extension in _TEXT:
        try:
            data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InvalidInput(f"a .{extension} file must be UTF-8 text (byte {exc.start})", field="file",
                               value=exc.start) from None
        return _TEXT[extension]
    raise InvalidInput("unsupported file: expected PNG, NPZ/NPY, CSV, JSON or text", field="file", value=name[:80])


@router.post("", status_code=201, dependencies=[Operator])
def upload_file(runtime: RuntimeDep, session: SessionDep, request: Request, file: Annotated[UploadFile, File()],
                idempotency_key: idempotency.IdempotencyKey = None) -> FileOut:
    """Upload a data file for jobs (PNG, NPZ/NPY, CSV, JSON, text)."""
    data = file.file.read()
    claim = idempotency.claim(request, idempotency_key, data, file.filename or "")
    replayed = idempotency.replay(session, claim)
    if replayed is not None:
        return replayed  # type: ignore[return-value]
    name = (file.filename or "file").rsplit("/", 1)[-1][:200]
    media = media_type_of(name, data)
    check_upload(media, data, int(runtime.settings.max_upload_mb * 2**20))  # NPY/NPZ headers, before storing
    row = UploadedFile(id=new_id("file"), name=name, media_type=media, bytes=len(data),
                       sha256=runtime.blobs.put(session, data), created_at=utcnow())
    session.add(row)
    out = FileOut(**row.model_dump())
    idempotency.remember(session, claim, 201, out)
    return idempotency.commit(session, claim) or out  # type: ignore[return-value]


@router.get("", dependencies=[Viewer])
def list_files(session: SessionDep, limit: Limit = 100, offset: Offset = 0) -> Page[FileOut]:
    total = session.exec(select(func.count()).select_from(UploadedFile)).one()
    rows = session.exec(select(UploadedFile).order_by(col(UploadedFile.created_at).desc())
                        .offset(offset).limit(limit)).all()
    return Page(items=[FileOut(**r.model_dump()) for r in rows], total=total)


@router.get("/{file_id}", dependencies=[Viewer])
def get_file(file_id: str, session: SessionDep) -> FileOut:
    return FileOut(**get_or_404(session, UploadedFile, file_id, field="file_id").model_dump())


@router.get("/{file_id}/content", dependencies=[Viewer], responses={200: {"content": {"application/octet-stream": {}}}})
def download_file(file_id: str, runtime: RuntimeDep, session: SessionDep) -> Response:
    row = get_or_404(session, UploadedFile, file_id, field="file_id")
    return Response(runtime.blobs.read(row.sha256), media_type=row.media_type,
                    headers={"Content-Disposition": attachment(row.name)})
