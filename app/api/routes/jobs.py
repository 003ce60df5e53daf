"""Jobs: submit, read, list, cancel, artifacts and Server-Sent Events progress."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Annotated, Literal

import anyio
from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.responses import JSONResponse, StreamingResponse
from sqlalchemy import bindparam, func, inspect
from sqlalchemy import select as sa_select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import defer
from sqlmodel import Session, col, select

from app.api import idempotency
from app.api.deps import Limit, Offset, Operator, RuntimeDep, SessionDep, Viewer
from app.api.job_events import JobWatch, TooManyStreams
from app.api.job_results import (
    ARTIFACTS_INLINE_MAX,
    Include,
    inlined,
    shown_input_hashes,
    shown_params,
    shown_result,
    wants,
)
from app.api.job_titles import job_titles
from app.api.schemas import ArtifactOut, JobCreate, JobOut, Page, ResumeRequest
from app.domain.errors import Conflict, ConformaError, InvalidInput, NotFound, TooLarge
from app.gcode.lines import GcodeReadError
from app.gcode.reader import ArcBudgetError, arc_chord_budget, beyond_size_budget
from app.jobs.results.models import ProgramEcho
from app.platform.lookup import get_or_404
from app.platform.models import Artifact, Job, JobReference, Machine, Trace
from app.platform.problems import PROBLEM_MEDIA_TYPE, problem
from app.runtime.machine_queue import request_resume, resume_preview

router = APIRouter(prefix="/api/v1/jobs", tags=["jobs"])
JobStatus = Literal["queued", "running", "succeeded", "needs_attention", "failed", "cancelled", "interrupted",
                    "waiting"]
SSE_POLL_S = 0.1
# Built once: the statements' compiled forms are cached, so a poll pays for execution only.
_JOB_TABLE = inspect(Job).local_table
_ARTIFACT_TABLE = inspect(Artifact).local_table
_JOB_BY_ID = (sa_select(*(c for c in _JOB_TABLE.c if c.name != "result"))
              .where(_JOB_TABLE.c.id == bindparam("job_id")))
_RESULT_OF_JOB = sa_select(_JOB_TABLE.c.result).where(_JOB_TABLE.c.id == bindparam("job_id"))
_ARTIFACTS_OF_JOB = (_ARTIFACT_TABLE.select().where(_ARTIFACT_TABLE.c.job_id == bindparam("job_id"))
                     .order_by(_ARTIFACT_TABLE.c.id))
_FIRST_ARTIFACTS = _ARTIFACTS_OF_JOB.limit(ARTIFACTS_INLINE_MAX + 1)
_ARTIFACT_COUNT = (sa_select(func.count()).select_from(_ARTIFACT_TABLE)
                   .where(_ARTIFACT_TABLE.c.job_id == bindparam("job_id")))
SSE_RETRY_AFTER_S = 5


def job_out(job: Job, artifacts: list[Artifact], include: Sequence[str] | None = None,
            artifact_count: int | None = None) -> JobOut:
    """The record of ``job`` (its result in brief unless ``include`` has "result", its large
    parameters unless it has "params"; its first ARTIFACTS_INLINE_MAX ``artifacts`` unless it
    has "artifacts"; ``artifact_count``: how many it wrote, when ``artifacts`` are not all of them)."""
    count = len(artifacts) if artifact_count is None else artifact_count
    listed = artifacts if wants(include, "artifacts") else artifacts[:ARTIFACTS_INLINE_MAX]
    return JobOut(
        **job.model_dump(exclude={"queue", "max_attempts", "worker", "lease_until", "revision", "enqueued_at",
                                  "result", "result_bytes", "result_summary", "params", "input_hashes"}),
        **shown_params(job.params, wants(include, "params")),
        **shown_input_hashes(job.input_hashes, wants(include, "input_hashes")),
        **shown_result(job, wants(include, "result")),
        artifacts=[ArtifactOut(name=a.name, media_type=a.media_type, bytes=a.bytes, sha256=a.sha256, meta=a.meta,
                               url=f"/api/v1/jobs/{job.id}/artifacts/{a.name}") for a in listed],
        artifact_count=count,
    )


def load_job_out(session: Session, job_id: str, include: list[str] | None = None) -> JobOut:
    job = get_or_404(session, Job, job_id)
    artifacts = session.exec(select(Artifact).where(col(Artifact.job_id) == job_id).order_by(col(Artifact.id))).all()
    return job_out(job, list(artifacts), include)


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
              top_level: Annotated[bool,
                                   Query(description="only jobs without a parent (hide workflow children)")] = False,
              created_after: Annotated[datetime | None, Query(description="ISO 8601; inclusive")] = None,
              created_before: Annotated[datetime | None, Query(description="ISO 8601; exclusive")] = None,
              limit: Limit = 100, offset: Offset = 0, include: Include = None) -> Page[JobOut]:
    """Jobs, newest first, filtered by kind, status, parent, part, machine and creation time;
    large results and long artifact lists in brief (see ``include``)."""
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
    jobs = session.exec(select(Job).options(defer(Job.result)).where(*filters)  # type: ignore[arg-type]
                        .order_by(col(Job.created_at).desc(), col(Job.id)).offset(offset).limit(limit)).all()
    ids = [j.id for j in jobs]
    shown = [j.id for j in jobs if inlined(j.result_bytes, wants(include, "result"))]
    results = dict(session.exec(select(Job.id, Job.result).where(Job.id.in_(shown))).all()) if shown else {}  # type: ignore[attr-defined]
    by_job: dict[str, list[Artifact]] = {i: [] for i in ids}
    if ids:
        for artifact in session.exec(select(Artifact).where(col(Artifact.job_id).in_(ids))
                                     .order_by(col(Artifact.id))).all():
            by_job[artifact.job_id].append(artifact)
    titles = job_titles(session, jobs)
    return Page(items=[job_out(Job.model_construct(**{**j.model_dump(exclude={"result"}), "result": results.get(j.id)}),
                               by_job[j.id], include).model_copy(update={"title": titles.get(j.id)})
                       for j in jobs], total=total)


def _utc(moment: datetime) -> datetime:
    """A naive time from a query is taken as UTC (jobs are stored in UTC)."""
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=UTC)


@router.get("/{job_id}", dependencies=[Viewer], response_model=JobOut)
def get_job(job_id: str, runtime: RuntimeDep, include: Include = None) -> Response:
    """One job.  The hot path of lab automation (polling): indexed Core queries and one
    serialisation, no ORM objects and no second validation of the response; a large result
    is read only for ``include=result``, and a long list of artifacts only for ``include=artifacts``."""
    with runtime.engine.connect() as conn:
        row = conn.execute(_JOB_BY_ID, {"job_id": job_id}).mappings().first()
        if row is None:
            raise NotFound(f"job {job_id!r} does not exist", field="job_id", value=job_id)
        every = wants(include, "artifacts")
        artifacts = conn.execute(_ARTIFACTS_OF_JOB if every else _FIRST_ARTIFACTS, {"job_id": job_id}).mappings().all()
        count = len(artifacts) if every or len(artifacts) <= ARTIFACTS_INLINE_MAX else \
            conn.execute(_ARTIFACT_COUNT, {"job_id": job_id}).scalar_one()
        whole = inlined(row["result_bytes"], wants(include, "result"))
        result = conn.execute(_RESULT_OF_JOB, {"job_id": job_id}).scalar() if whole else None
    body = job_out(Job.model_construct(**row, result=result), [Artifact.model_construct(**a) for a in artifacts],
                   include, count)
    return Response(body.model_dump_json(), media_type="application/json")


@router.post("/{job_id}/cancel", status_code=202, dependencies=[Operator])
def cancel_job(job_id: str, runtime: RuntimeDep, session: SessionDep) -> JobOut:
    """Cancel a queued job at once, ask a running one to stop, or abandon an interrupted one;
    409 if it already finished."""
    job = get_or_404(session, Job, job_id)
    if runtime.store.request_cancel(job_id) is None:
        session.refresh(job)
        state = ("cancel was already requested" if job.cancel_requested and job.status == "running"
                 else f"it is {job.status}")
        raise Conflict(f"job {job_id!r} cannot be cancelled: {state}", field="job_id", value=job_id)
    for child in session.exec(select(Job.id).where(Job.parent_id == job_id)).all():
        runtime.store.request_cancel(child)
    session.expire_all()
    return load_job_out(session, job_id)


@router.get("/{job_id}/artifacts", dependencies=[Viewer])
def list_artifacts(job_id: str, session: SessionDep) -> list[ArtifactOut]:
    """The files a job wrote, in the order it wrote them (name, type, size, sha256, url)."""
    return load_job_out(session, job_id, ["artifacts"]).artifacts


@router.get("/{job_id}/artifacts/{name}", dependencies=[Viewer],
            responses={200: {"content": {"application/octet-stream": {}}}})
def get_artifact(job_id: str, name: str, runtime: RuntimeDep, session: SessionDep) -> Response:
    get_or_404(session, Job, job_id)
    artifact = session.exec(select(Artifact).where(Artifact.job_id == job_id, Artifact.name == name)).first()
    if artifact is None:
        raise NotFound(f"job {job_id!r} has no artifact {name!r}", field="name", value=name)
    return Response(runtime.blobs.read(artifact.sha256), media_type=artifact.media_type,
                    headers={"Content-Disposition": f'attachment; filename="{name}"', "ETag": f'"{artifact.sha256}"'})


@router.get("/{job_id}/artifacts/{name}/summary", dependencies=[Viewer],
            responses={413: {"description": "the program needs more memory or time than a summary may take"},
                       422: {"description": "the artifact is not a G-code program, or its arcs need more chords "
                                            "than its size allows"}})
def artifact_summary(job_id: str, name: str, request: Request, runtime: RuntimeDep, session: SessionDep) -> dict:
    """A G-code artifact as an operator reads it before printing: its lines, the
    estimated time (s) and, for a five-axis program, its A/C angles and tip speed along the
    path (``rotary``: s_mm, a_deg, c_deg, tip_speed_mm_s; see app.viewer.program_profile).

    Bounded: a program of at most ``SUMMARY_INLINE_BYTES`` whose arcs need at most
    ``SUMMARY_INLINE_CHORDS`` chords is read here (~0.5 s of CPU at most); any other in a child
    process with CONFORMA_JOB_MEMORY_MB of memory and CONFORMA_IMPORT_TIME_S of time, its
    arcs' chords counted against the budget of its size before any is made
    (:func:`app.gcode.reader.arc_chord_budget`): a 422 naming the artifact and the line
    beyond it, a 413 beyond the memory or time."""
    from app.viewer.program_profile import program_summary

    job = get_or_404(session, Job, job_id)
    artifact = session.exec(select(Artifact).where(Artifact.job_id == job_id, Artifact.name == name)).first()
    if artifact is None:
        raise NotFound(f"job {job_id!r} has no artifact {name!r}", field="name", value=name)
    if artifact.media_type != "text/x-gcode":
        raise InvalidInput(f"artifact {name!r} is {artifact.media_type}, not a G-code program", field="name",
                           value=name)
    echo = ProgramEcho.of_any(job)
    pivot = echo.pivot or [0.0, 0.0, 0.0]
    tcp = echo.post == "linuxcnc_xyzac_trt"
    dispense = (echo.dispense_on, echo.dispense_off)
    key = (artifact.sha256, tuple(pivot), tcp, dispense)
    if key not in _SUMMARIES:
        summary: dict | InvalidInput | None = None
        if artifact.bytes <= SUMMARY_INLINE_BYTES:
            text = runtime.blobs.read(artifact.sha256).decode("utf-8", errors="replace")
            try:
                # at most the size's budget: a refusal beyond it names the first arc over it
                budget = min(SUMMARY_INLINE_CHORDS, arc_chord_budget(artifact.bytes))
                summary = program_summary(text, pivot, tcp, *dispense, max_arc_chords=budget)
            except ArcBudgetError as exc:        # beyond its size's budget: refused; else the child reads it
                refusal = beyond_size_budget(exc, artifact.bytes)
                summary = None if refusal is None else _refusal(name, refusal)
            except GcodeReadError as exc:
                summary = _refusal(name, exc)
        if summary is None:
            summary = _summary_isolated(runtime, request, artifact, name, pivot, tcp, dispense)
        while len(_SUMMARIES) >= 64:
            _SUMMARIES.pop(next(iter(_SUMMARIES)))
        _SUMMARIES[key] = summary
    cached = _SUMMARIES[key]
    if isinstance(cached, InvalidInput):
        raise InvalidInput(cached.message, field=cached.field, value=cached.value)
    return {"job_id": job_id, "name": name, "kind": job.kind, "sha256": artifact.sha256, **cached}


#: a G-code artifact up to this size (bytes) whose arcs need at most ``SUMMARY_INLINE_CHORDS``
#: chords is summarised in the request (~20 us per move or chord: ~0.5 s of CPU at most)
SUMMARY_INLINE_BYTES = 64 * 1024
SUMMARY_INLINE_CHORDS = 20_000


def _refusal(name: str, exc: ConformaError) -> InvalidInput:
    """The 422 of an artifact whose program cannot be read: field ``name``, the artifact and
    what the reader said (the line, the chord budget)."""
    value = {"name": name, **(exc.value if isinstance(exc.value, dict) else {"detail": exc.value})}
    return InvalidInput(f"artifact {name!r}: {exc.message}", field="name", value=value)


def _summary_isolated(runtime, request: Request, artifact: Artifact, name: str, pivot: list[float],
                      tcp: bool, dispense: tuple[str | None, str | None]) -> dict | InvalidInput:
    """The summary computed in a bounded child process (:func:`app.runtime.isolated.call_isolated`)
    from the stored file; a refusal of its program as a 422 (returned, to be remembered);
    TooLarge (413) naming the artifact beyond the memory or time; killed when the client
    goes away."""
    from app.runtime.isolated import call_isolated
    from app.viewer.program_profile import program_summary_file

    settings = runtime.settings
    what = f"the summary of artifact {name!r}"
    try:
        summary: dict = call_isolated(
            program_summary_file, str(runtime.blobs.path(artifact.sha256)), pivot, tcp, *dispense,
            memory_bytes=int(settings.job_memory_mb * 2**20), time_s=settings.import_time_s, what=what,
            cancelled=lambda: bool(anyio.from_thread.run(request.is_disconnected)))
    except TooLarge as exc:
        raise TooLarge(exc.message, field="name", value={"name": name, "bytes": artifact.bytes}) from None
    except InvalidInput as exc:
        return _refusal(name, exc)
    return summary


_SUMMARIES: dict[tuple, dict | InvalidInput] = {}  # by content (and frame): a summary (or refusal) never changes


@router.get("/{job_id}/resume", dependencies=[Operator],
            responses={409: {"description": "the job is not interrupted, or not a machine job"},
                       502: {"description": "the machine's firmware answered nonsense to where it stands"}})
def preview_resume(job_id: str, runtime: RuntimeDep, session: SessionDep) -> dict:
    """What ``POST /jobs/{id}/resume`` will do, before the operator confirms: the command it
    resumes at (``line``), the ``basis`` and its ``detail``, the commands (``repeats``) and
    moves (``repeat_moves``) that may run a second time, ``skipped: 0`` and a ``summary``.
    Reconnects a machine whose link was lost (no motion) to ask where it stands."""
    job = get_or_404(session, Job, job_id)
    machine_id = (job.params or {}).get("machine_id")
    if job.status != "interrupted" or not machine_id:
        raise Conflict(f"job {job_id!r} is {job.status}, not an interrupted machine job: nothing to resume",
                       field="job_id", value=job_id)
    row = get_or_404(session, Machine, machine_id)
    return resume_preview(runtime, job, row)


@router.post("/{job_id}/resume", status_code=202, dependencies=[Operator],
             responses={409: {"description": "the job is not interrupted"}, 422: {"description": "no confirmation"}})
def resume_job(job_id: str, body: ResumeRequest, runtime: RuntimeDep, session: SessionDep) -> JobOut:
    """Resume an ``interrupted`` machine job: it reconnects, asks the machine which command
    is known executed, re-homes and continues from there.  The machine moves: the body
    must say ``{"confirm": true}``."""
    if body.confirm is not True:
        raise InvalidInput("resuming moves the machine: send {\"confirm\": true}", field="confirm",
                           value=body.confirm)
    job = get_or_404(session, Job, job_id)
    if job.status != "interrupted" or not request_resume(runtime.store, job):
        session.refresh(job)
        raise Conflict(f"job {job_id!r} is {job.status}, not interrupted: nothing to resume", field="job_id",
                       value=job_id)
    runtime.enqueue(job_id, job.queue)
    session.expire_all()
    return load_job_out(session, job_id)


@router.post("/{job_id}/abandon", dependencies=[Operator],
             responses={409: {"description": "the job is neither interrupted nor waiting"}})
def abandon_job(job_id: str, runtime: RuntimeDep, session: SessionDep) -> JobOut:
    """Give up an ``interrupted`` machine job or a ``waiting`` closed loop (it becomes
    cancelled; the machine is free)."""
    job = get_or_404(session, Job, job_id)
    if runtime.store.abandon(job_id) is None:
        raise Conflict(f"job {job_id!r} is {job.status}, neither interrupted nor waiting: nothing to abandon",
                       field="job_id", value=job_id)
    session.expire_all()
    return load_job_out(session, job_id)


def _watch(request: Request, runtime) -> JobWatch:
    watch = getattr(request.app.state, "job_watch", None)
    if watch is None:  # made on the event loop thread: no race
        watch = JobWatch(runtime.engine, per_key=runtime.settings.sse_streams_per_key, poll_s=SSE_POLL_S)
        request.app.state.job_watch = watch
    return watch


@router.get("/{job_id}/events", dependencies=[Viewer],
            responses={200: {"content": {"text/event-stream": {}}, "description": "progress and status events"},
                       429: {"description": "this key holds too many open streams (Retry-After)"}})
async def job_events(job_id: str, request: Request, runtime: RuntimeDep,
                     last_event_id: Annotated[str | None, Header()] = None) -> Response:
    """Server-Sent Events: ``progress`` while it runs and ``status`` on each change; ends when
    finished.  Async, fed by one poller for all streams; capped per API key (429)."""
    watch = _watch(request, runtime)
    credential = request.headers.get("authorization", "").removeprefix("Bearer ").strip() \
        or request.headers.get("x-api-key")
    key = watch.key_of(credential)
    try:
        watch.admit(key)
    except TooManyStreams as exc:
        return JSONResponse(problem(429, "Too many streams", str(exc)), status_code=429,
                            media_type=PROBLEM_MEDIA_TYPE, headers={"Retry-After": str(SSE_RETRY_AFTER_S)})
    try:
        subscriber = await watch.subscribe(job_id)
    except BaseException:
        watch.release(key)
        raise
    if subscriber is None:
        watch.release(key)
        raise NotFound(f"job {job_id!r} does not exist", field="job_id", value=job_id)
    return StreamingResponse(watch.events(subscriber, last_event_id, key), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
