"""Traces: circuit conductors on a part, stored with their draped nominal polyline."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body
from sqlalchemy import func
from sqlmodel import Session, select

from app.api.deps import Limit, Offset, Operator, RuntimeDep, SessionDep, Viewer
from app.api.schemas import Page, TraceCreate, TraceOut
from app.errors import Conflict
from app.models import JobReference, Part, Trace
from app.records import build_trace, get_or_404

router = APIRouter(prefix="/api/v1", tags=["traces"])
MAX_IMPORT = 1000


def trace_out(trace: Trace) -> TraceOut:
    data = trace.model_dump()
    data["z_range"] = [data.pop("z_min"), data.pop("z_max")]
    return TraceOut(**data)


@router.post("/parts/{part_id}/traces", status_code=201, dependencies=[Operator])
def create_trace(part_id: str, body: TraceCreate, runtime: RuntimeDep, session: SessionDep) -> TraceOut:
    """Create a trace; 422 if it leaves the part's surface (naming the first offending point)."""
    part = get_or_404(session, Part, part_id)
    trace = build_trace(runtime.meshes, part, body)
    session.add(trace)
    session.commit()
    return trace_out(trace)


@router.post("/parts/{part_id}/traces:import", status_code=201, dependencies=[Operator])
def import_traces(part_id: str, runtime: RuntimeDep, session: SessionDep,
                  body: Annotated[list[TraceCreate], Body(min_length=1, max_length=MAX_IMPORT)]) -> Page[TraceOut]:
    """Create many traces at once: all or nothing (the first bad one is named by its index)."""
    part = get_or_404(session, Part, part_id)
    traces = [build_trace(runtime.meshes, part, item, field_prefix=str(i)) for i, item in enumerate(body)]
    session.add_all(traces)
    session.commit()
    return Page(items=[trace_out(t) for t in traces], total=len(traces))


@router.get("/parts/{part_id}/traces", dependencies=[Viewer])
def list_traces(part_id: str, session: SessionDep, limit: Limit = 100,
                offset: Offset = 0) -> Page[TraceOut]:
    get_or_404(session, Part, part_id)
    total = session.exec(select(func.count()).select_from(Trace).where(Trace.part_id == part_id)).one()
    rows = session.exec(select(Trace).where(Trace.part_id == part_id).order_by(Trace.created_at, Trace.id)
                        .offset(offset).limit(limit)).all()
    return Page(items=[trace_out(t) for t in rows], total=total)


@router.get("/traces/{trace_id}", dependencies=[Viewer])
def get_trace(trace_id: str, session: SessionDep) -> TraceOut:
    return trace_out(get_or_404(session, Trace, trace_id))


@router.delete("/traces/{trace_id}", status_code=204, dependencies=[Operator])
def delete_trace(trace_id: str, session: SessionDep) -> None:
    """Delete a trace; 409 while jobs reference it."""
    trace = get_or_404(session, Trace, trace_id)
    _refuse_if_referenced(session, trace_id)
    session.delete(trace)
    session.commit()


def _refuse_if_referenced(session: Session, record_id: str) -> None:
    refs = session.exec(select(JobReference.job_id).where(JobReference.ref_id == record_id)).all()
    if refs:
        raise Conflict(f"{record_id!r} is referenced by job(s) {', '.join(sorted(set(refs))[:5])}",
                       field="trace_id", value=record_id)
