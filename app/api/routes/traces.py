"""Traces: circuit conductors on a part, stored with their draped nominal polyline."""

from __future__ import annotations

from collections.abc import Mapping
from functools import partial
from typing import Annotated, Any

from fastapi import APIRouter, Body, Request, Response
from sqlalchemy import func
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, col, select

from app.api import idempotency
from app.api.deps import Limit, Offset, Operator, RuntimeDep, SessionDep, Viewer
from app.api.schemas import NominalOut, Page, TraceCreate, TraceOut
from app.domain.errors import Conflict, NotFound
from app.parts.traces import build_trace, build_traces, collection_paused, insert_traces
from app.platform.db import lock_for_delete
from app.platform.lookup import get_or_404
from app.platform.models import JobReference, Part, Trace

router = APIRouter(prefix="/api/v1", tags=["traces"])
MAX_IMPORT = 1000


def trace_out(trace: Trace | Mapping[str, Any]) -> TraceOut:
    """The API form of a stored trace (a record or its column values), built without
    validating it again (the record was validated when it was made; its nominal polyline is
    thousands of floats)."""
    get = trace.__getitem__ if isinstance(trace, Mapping) else partial(getattr, trace)
    fields = {name: get(name) for name in TraceOut.model_fields if name not in ("z_range", "nominal")}
    return TraceOut.model_construct(**fields, z_range=[get("z_min"), get("z_max")],
                                    nominal=NominalOut.model_construct(**get("nominal")))


@router.post("/parts/{part_id}/traces", status_code=201, dependencies=[Operator])
def create_trace(part_id: str, body: TraceCreate, runtime: RuntimeDep, session: SessionDep, request: Request,
                 idempotency_key: idempotency.IdempotencyKey = None) -> TraceOut:
    """Create a trace; 422 if it leaves the part's surface (naming the first offending point);
    404 if the part does not exist (also when it is deleted while the trace is built)."""
    claim = idempotency.claim(request, idempotency_key, idempotency.canonical(body))
    replayed = idempotency.replay(session, claim)
    if replayed is not None:
        return replayed  # type: ignore[return-value]
    part = get_or_404(session, Part, part_id)
    trace = build_trace(runtime.meshes, part, body)
    out = trace_out(trace)
    session.add(trace)
    idempotency.remember(session, claim, 201, out)
    return _commit(session, claim, part_id) or out  # type: ignore[return-value]


@router.post("/parts/{part_id}/traces:import", status_code=201, dependencies=[Operator])
def import_traces(part_id: str, runtime: RuntimeDep, session: SessionDep, request: Request,
                  body: Annotated[list[TraceCreate], Body(min_length=1, max_length=MAX_IMPORT)],
                  idempotency_key: idempotency.IdempotencyKey = None) -> Page[TraceOut]:
    """Create many traces at once: all or nothing (the first bad one is named by its index)."""
    claim = idempotency.claim(request, idempotency_key, *(idempotency.canonical(item) for item in body))
    replayed = idempotency.replay(session, claim)
    if replayed is not None:
        return replayed  # type: ignore[return-value]
    part = get_or_404(session, Part, part_id)
    with collection_paused():
        rows = build_traces(runtime.meshes, part, body)
        out = Page[TraceOut](items=[trace_out(row) for row in rows], total=len(rows))
        try:
            insert_traces(session, rows)
        except IntegrityError:
            raise _part_gone(part_id) from None
        idempotency.remember(session, claim, 201, out)
        return _commit(session, claim, part_id) or out  # type: ignore[return-value]


def _commit(session: Session, claim: idempotency.Claim | None, part_id: str) -> Response | None:
    """Commit new traces: the foreign key refuses them if the part was deleted meanwhile (404);
    a concurrent request with the same Idempotency-Key wins and is replayed."""
    try:
        return idempotency.commit(session, claim)
    except IntegrityError:
        raise _part_gone(part_id) from None


def _part_gone(part_id: str) -> NotFound:
    return NotFound(f"part {part_id!r} does not exist (deleted while the trace was built)",
                    field="part_id", value=part_id)


@router.get("/parts/{part_id}/traces", dependencies=[Viewer])
def list_traces(part_id: str, session: SessionDep, limit: Limit = 100,
                offset: Offset = 0) -> Page[TraceOut]:
    get_or_404(session, Part, part_id)
    total = session.exec(select(func.count()).select_from(Trace).where(Trace.part_id == part_id)).one()
    rows = session.exec(select(Trace).where(col(Trace.part_id) == part_id)
                        .order_by(col(Trace.created_at), col(Trace.id))
                        .offset(offset).limit(limit)).all()
    return Page(items=[trace_out(t) for t in rows], total=total)


@router.get("/traces/{trace_id}", dependencies=[Viewer])
def get_trace(trace_id: str, session: SessionDep) -> TraceOut:
    return trace_out(get_or_404(session, Trace, trace_id))


@router.delete("/traces/{trace_id}", status_code=204, dependencies=[Operator])
def delete_trace(trace_id: str, session: SessionDep) -> None:
    """Delete a trace; 409 while jobs reference it (checked under the trace's lock, so a job
    submitted at the same moment either is seen here or finds the trace gone)."""
    if not lock_for_delete(session, Trace, [trace_id]):
        session.rollback()
        raise NotFound(f"trace {trace_id!r} does not exist", field="trace_id", value=trace_id)
    trace = get_or_404(session, Trace, trace_id)
    try:
        _refuse_if_referenced(session, trace_id)
    except Conflict:
        session.rollback()
        raise
    session.delete(trace)
    session.commit()


def _refuse_if_referenced(session: Session, record_id: str) -> None:
    refs = session.exec(select(JobReference.job_id).where(JobReference.ref_id == record_id)).all()
    if refs:
        raise Conflict(f"{record_id!r} is referenced by job(s) {', '.join(sorted(set(refs))[:5])}",
                       field="trace_id", value=record_id)
