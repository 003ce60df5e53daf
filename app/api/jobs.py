"""Jobs: submit, read, list, cancel, artifacts and Server-Sent Events progress."""

from __future__ import annotations

import json
import time
from datetime import datetime, timezone
from collections.abc import Iterator
from typing import Annotated, Literal

from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.responses import StreamingResponse
from sqlalchemy import bindparam, func
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, select

from app.api import idempotency
from app.api.deps import Limit, Offset, Operator, RuntimeDep, SessionDep, Viewer
from app.api.schemas import ArtifactOut, JobCreate, JobOut, Page
from app.errors import Conflict, NotFound
from app.models import TERMINAL_STATES, Artifact, Job, JobReference, Trace
from app.records import get_or_404

router = APIRouter(prefix="/api/v1/jobs", tags=["jobs"])
JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
SSE_POLL_S = 0.1
# Built once: the statements' compiled forms are cached, so a poll pays for execution only.
_JOB_BY_ID = Job.__table__.select().where(Job.__table__.c.id == bindparam("job_id"))
_ARTIFACTS_OF_JOB = (Artifact.__table__.select().where(Artifact.__table__.c.job_id == bindparam("job_id"))
                     .order_by(Artifact.__table__.c.id))
SSE_KEEPALIVE_S = 15.0


def job_out(job: Job, artifacts: list[Artifact]) -> JobOut:
    return JobOut(
        **job.model_dump(exclude={"queue", "max_attempts", "worker", "lease_until", "revision", "enqueued_at"}),
        artifacts=[ArtifactOut(name=a.name, media_type=a.media_type, bytes=a.bytes, sha256=a.sha256, meta=a.meta,
                               url=f"/api/v1/jobs/{job.id}/artifacts/{a.name}") for a in artifacts],
    )


def load_job_out(session: Session, job_id: str) -> JobOut:
    job = get_or_404(session, Job, job_id)
    artifacts = session.exec(select(Artifact).where(Artifact.job_id == job_id).order_by(Artifact.id)).all()
    return job_out(job, list(artifacts))


@router.post("", status_code=202, dependencies=[Operator])
def submit_job(body: JobCreate, runtime: RuntimeDep, session: SessionDep, request: Request, response: Response,
               idempotency_key: idempotency.IdempotencyKey = None) -> JobOut:
    """Queue a job; its parameters are checked now (422), not when it runs.  The job exists
    exactly when this 202 is sent: it is created in one transaction (with its references
    re-checked under a lock and the Idempotency-Key's answer) and the answer is built from
    that transaction's record, with no further query that could fail after it."""
    claim = idempotency.claim(request, idempotency_key, idempotency.canonical(body))
    replayed = idempotency.replay(session, claim)
    if replayed is not None:
        return replayed  # type: ignore[return-value]

    def remember(tx: Session, job: Job) -> None:
        idempotency.remember(tx, claim, 202, job_out(job, []), f"/api/v1/jobs/{job.id}")

    try:
        job = runtime.submit(body.kind, body.params, before_commit=remember if claim else None)
    except IntegrityError:
        winner = idempotency.lost_race(session, claim)
        if winner is None:
            raise
        return winner  # type: ignore[return-value]
    response.headers["Location"] = f"/api/v1/jobs/{job.id}"
    return job_out(job, [])


@router.get("", dependencies=[Viewer])
def list_jobs(session: SessionDep, kind: str | None = None, status: JobStatus | None = None,
              parent_id: str | None = None,
              part_id: Annotated[str | None, Query(max_length=40, description=(
                  "jobs that read this part or one of its traces"))] = None,
              machine_id: Annotated[str | None, Query(max_length=40, description="jobs that use this machine")] = None,
              top_level: Annotated[bool, Query(description="only jobs without a parent (hide workflow children)")] = False,
              created_after: Annotated[datetime | None, Query(description="ISO 8601; inclusive")] = None,
              created_before: Annotated[datetime | None, Query(description="ISO 8601; exclusive")] = None,
              limit: Limit = 100, offset: Offset = 0) -> Page[JobOut]:
    """Jobs, newest first, filtered by kind, status, parent, part, machine and creation time."""
    filters = [c for c in (Job.kind == kind if kind else None, Job.status == status if status else None,
                           Job.parent_id == parent_id if parent_id else None,
                           Job.parent_id.is_(None) if top_level else None,  # type: ignore[union-attr]
                           Job.created_at >= _utc(created_after) if created_after else None,
                           Job.created_at < _utc(created_before) if created_before else None) if c is not None]
    if part_id:
        traces = select(Trace.id).where(Trace.part_id == part_id)
        filters.append(Job.id.in_(select(JobReference.job_id).where(  # type: ignore[attr-defined]
            ((JobReference.ref_kind == "part") & (JobReference.ref_id == part_id))
            | ((JobReference.ref_kind == "trace") & JobReference.ref_id.in_(traces)))))  # type: ignore[attr-defined]
    if machine_id:
        filters.append(Job.id.in_(select(JobReference.job_id).where(  # type: ignore[attr-defined]
            JobReference.ref_kind == "machine", JobReference.ref_id == machine_id)))
    total = session.exec(select(func.count()).select_from(Job).where(*filters)).one()
    jobs = session.exec(select(Job).where(*filters).order_by(Job.created_at.desc(), Job.id).offset(offset).limit(limit)).all()
    ids = [j.id for j in jobs]
    by_job: dict[str, list[Artifact]] = {i: [] for i in ids}
    if ids:
        for artifact in session.exec(select(Artifact).where(Artifact.job_id.in_(ids)).order_by(Artifact.id)).all():
            by_job[artifact.job_id].append(artifact)
    return Page(items=[job_out(j, by_job[j.id]) for j in jobs], total=total)


def _utc(moment: datetime) -> datetime:
    """A naive time from a query is taken as UTC (jobs are stored in UTC)."""
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=timezone.utc)


@router.get("/{job_id}", dependencies=[Viewer], response_model=JobOut)
def get_job(job_id: str, runtime: RuntimeDep) -> Response:
    """One job.  The hot path of lab automation (polling): two indexed Core queries and one
    serialisation, no ORM objects and no second validation of the response."""
    with runtime.engine.connect() as conn:
        row = conn.execute(_JOB_BY_ID, {"job_id": job_id}).mappings().first()
        if row is None:
            raise NotFound(f"job {job_id!r} does not exist", field="job_id", value=job_id)
        artifacts = conn.execute(_ARTIFACTS_OF_JOB, {"job_id": job_id}).mappings().all()
    body = job_out(Job.model_construct(**row), [Artifact.model_construct(**a) for a in artifacts])
    return Response(body.model_dump_json(), media_type="application/json")


@router.post("/{job_id}/cancel", status_code=202, dependencies=[Operator])
def cancel_job(job_id: str, runtime: RuntimeDep, session: SessionDep) -> JobOut:
    """Cancel a queued job at once or ask a running one to stop; 409 if it already finished."""
    job = get_or_404(session, Job, job_id)
    if runtime.store.request_cancel(job_id) is None:
        session.refresh(job)
        state = "cancel was already requested" if job.cancel_requested and job.status == "running" else f"it is {job.status}"
        raise Conflict(f"job {job_id!r} cannot be cancelled: {state}", field="job_id", value=job_id)
    for child in session.exec(select(Job.id).where(Job.parent_id == job_id)).all():
        runtime.store.request_cancel(child)
    session.expire_all()
    return load_job_out(session, job_id)


@router.get("/{job_id}/artifacts", dependencies=[Viewer])
def list_artifacts(job_id: str, session: SessionDep) -> list[ArtifactOut]:
    """The files a job wrote, in the order it wrote them (name, type, size, sha256, url)."""
    return load_job_out(session, job_id).artifacts


@router.get("/{job_id}/artifacts/{name}", dependencies=[Viewer],
            responses={200: {"content": {"application/octet-stream": {}}}})
def get_artifact(job_id: str, name: str, runtime: RuntimeDep, session: SessionDep) -> Response:
    get_or_404(session, Job, job_id)
    artifact = session.exec(select(Artifact).where(Artifact.job_id == job_id, Artifact.name == name)).first()
    if artifact is None:
        raise NotFound(f"job {job_id!r} has no artifact {name!r}", field="name", value=name)
    return Response(runtime.blobs.read(artifact.sha256), media_type=artifact.media_type,
                    headers={"Content-Disposition": f'attachment; filename="{name}"', "ETag": f'"{artifact.sha256}"'})


@router.get("/{job_id}/events", dependencies=[Viewer],
            responses={200: {"content": {"text/event-stream": {}}, "description": "progress and status events"}})
def job_events(job_id: str, runtime: RuntimeDep, session: SessionDep,
               last_event_id: Annotated[str | None, Header()] = None) -> StreamingResponse:
    """Server-Sent Events: ``progress`` while it runs and ``status`` on each change; ends when finished."""
    get_or_404(session, Job, job_id)
    return StreamingResponse(_event_stream(runtime.engine, job_id, last_event_id), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


def _event_stream(engine, job_id: str, last_event_id: str | None) -> Iterator[str]:  # type: ignore[no-untyped-def]
    seen_revision = int(last_event_id) if last_event_id and last_event_id.isdigit() else -1
    last_status = None
    last_sent = time.monotonic()
    while True:
        with Session(engine) as session:
            job = session.get(Job, job_id)
        if job is None:
            return
        if job.revision != seen_revision:
            seen_revision = job.revision
            event = "status" if job.status != last_status else "progress"
            last_status = job.status
            payload = {"id": job.id, "status": job.status, "progress": job.progress, "message": job.message}
            yield f"id: {job.revision}\nevent: {event}\ndata: {json.dumps(payload)}\n\n"
            last_sent = time.monotonic()
        if job.status in TERMINAL_STATES:
            return
        if time.monotonic() - last_sent > SSE_KEEPALIVE_S:
            yield ": keepalive\n\n"
            last_sent = time.monotonic()
        time.sleep(SSE_POLL_S)
