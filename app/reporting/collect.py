"""Gather what a run report shows from the database: the jobs of one measurement session.

A session is a ``closed_loop`` job with its children, a ``jetting_run`` job, or a ``probe_run``
job with its plan and every job that (transitively) read it — reconstructions, compensations, prints — as
the job references record them.  Records are returned as plain dictionaries so the
renderer needs no database.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from sqlmodel import Session, col, select

from app.domain.errors import InvalidInput
from app.platform.lookup import get_or_404
from app.platform.models import Artifact, Job, JobReference, Machine, Part, Trace

REPORTABLE = ("closed_loop", "probe_run", "jetting_run")
MAX_JOBS = 2000  # a session of 300 traces has ~1,200 jobs; beyond this the report refuses


@dataclass
class RunRecords:
    """Everything the report shows; each entry a plain dict (a row's fields)."""

    root: dict[str, Any]
    jobs: list[dict[str, Any]] = field(default_factory=list)        # every job of the session, oldest first
    artifacts: dict[str, list[dict[str, Any]]] = field(default_factory=dict)  # job id -> its artifacts
    traces: dict[str, dict[str, Any]] = field(default_factory=dict)
    part: dict[str, Any] | None = None
    machine: dict[str, Any] | None = None

    def of_kind(self, kind: str) -> list[dict[str, Any]]:
        return [job for job in self.jobs if job["kind"] == kind]


def _downstream(session: Session, start: list[str]) -> set[str]:
    """Ids of every job that read one of ``start`` (directly or through others)."""
    seen: set[str] = set()
    frontier = list(start)
    while frontier and len(seen) < MAX_JOBS:
        rows = session.exec(select(JobReference.job_id).where(JobReference.ref_kind == "job",
                                                              JobReference.ref_id.in_(frontier))).all()  # type: ignore[attr-defined]
        frontier = [job_id for job_id in rows if job_id not in seen]
        seen.update(frontier)
    return seen


def collect_run(session: Session, job_id: str) -> RunRecords:
    """The session rooted at ``job_id`` (a closed_loop or probe_run job)."""
    root = get_or_404(session, Job, job_id)
    if root.kind not in REPORTABLE:
        raise InvalidInput(f"a run report is made for a closed_loop, probe_run or jetting_run job, not {root.kind!r}",
                           field="job_id", value=job_id)
    ids = {root.id}
    if root.kind == "closed_loop":
        ids |= set(session.exec(select(Job.id).where(Job.parent_id == root.id)).all())
    else:
        plan_id = (root.params or {}).get("plan_job_id")
        if plan_id:
            ids.add(plan_id)
    ids |= _downstream(session, sorted(ids))
    if len(ids) > MAX_JOBS:
        raise InvalidInput(f"the session has more than {MAX_JOBS} jobs", field="job_id", value=job_id)
    jobs = session.exec(select(Job).where(col(Job.id).in_(ids)).order_by(col(Job.created_at), col(Job.id))).all()
    records = RunRecords(root=root.model_dump(mode="json"), jobs=[j.model_dump(mode="json") for j in jobs])
    for artifact in session.exec(select(Artifact).where(col(Artifact.job_id).in_(ids))
                                 .order_by(col(Artifact.id))).all():
        records.artifacts.setdefault(artifact.job_id, []).append(artifact.model_dump(mode="json"))
    trace_ids = {tid for job in records.jobs for tid in _trace_ids(job["params"])}
    for trace in session.exec(select(Trace).where(Trace.id.in_(trace_ids))).all():  # type: ignore[attr-defined]
        records.traces[trace.id] = trace.model_dump(mode="json", exclude={"nominal"})
    part_id = (root.params or {}).get("part_id") or next(
        (t["part_id"] for t in records.traces.values()), None)
    part = session.get(Part, part_id) if part_id else None
    records.part = part.model_dump(mode="json") if part else None
    machine_id = (root.params or {}).get("machine_id")
    machine = session.get(Machine, machine_id) if machine_id else None
    records.machine = machine.model_dump(mode="json") if machine else None
    return records


def _trace_ids(params: dict[str, Any]) -> list[str]:
    ids = [params["trace_id"]] if isinstance(params.get("trace_id"), str) else []
    ids += [t for t in params.get("trace_ids") or [] if isinstance(t, str)]
    return ids
