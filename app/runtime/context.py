"""What a running job sees: its parameters, progress reporting, cancel, inputs, artifacts.

Job kinds are thin adapters; everything they need from the service goes through this
object, so a kind never opens the database or the blob directory itself.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

from sqlmodel import Session, col, select

from app.domain.errors import Cancelled, ConformaError, NotFound
from app.jobs.inputs import succeeded_job
from app.platform.artifacts import add_artifact
from app.platform.lookup import get_or_404
from app.platform.models import TERMINAL_STATES, Artifact, Job, Machine, Part, Trace, UploadedFile, utcnow
from app.runtime.store import Claim

_ARTIFACTS = Artifact.__table__  # type: ignore[attr-defined]

if TYPE_CHECKING:
    import trimesh

    from app.runtime.engine import Runtime


class JobContext:
    """The service side of one running attempt of one job."""

    def __init__(self, runtime: Runtime, claim: Claim) -> None:
        self.runtime = runtime
        self.claim = claim
        self.job_id = claim.job_id
        self.cancel_event = threading.Event()
        self.lost_event = threading.Event()

    # progress and cancel ---------------------------------------------------------
    def progress(self, fraction: float, message: str | None = None) -> None:
        """Report progress (0..1); renews the lease.  Raises Cancelled when asked to stop."""
        answer = self.runtime.store.heartbeat(self.claim, fraction, message)
        if answer is None:
            self.lost_event.set()
        elif answer:
            self.cancel_event.set()
        self.check_cancelled()

    def check_cancelled(self) -> None:
        if self.cancel_event.is_set():
            raise Cancelled("the job was cancelled", field="job_id", value=self.job_id)
        if self.lost_event.is_set():
            raise Cancelled("this attempt lost its lease to another worker", field="job_id", value=self.job_id)

    # inputs ----------------------------------------------------------------------
    def session(self) -> Session:
        return Session(self.runtime.engine, expire_on_commit=False)

    def part(self, part_id: str) -> Part:
        with self.session() as session:
            return get_or_404(session, Part, part_id)

    def mesh(self, part_id: str) -> trimesh.Trimesh:
        return self.runtime.meshes.mesh(self.part(part_id))

    def trace(self, trace_id: str) -> Trace:
        with self.session() as session:
            return get_or_404(session, Trace, trace_id)

    def traces(self, trace_ids: list[str]) -> list[Trace]:
        """The traces ``trace_ids`` in order, read in one query (a board's thousand); a missing
        one is a NotFound naming it."""
        with self.session() as session:
            rows = {t.id: t for t in session.exec(select(Trace).where(Trace.id.in_(trace_ids))).all()}  # type: ignore[attr-defined]
        missing = next((t for t in trace_ids if t not in rows), None)
        if missing is not None:
            raise NotFound(f"trace {missing!r} does not exist", field="trace_id", value=missing)
        return [rows[t] for t in trace_ids]

    def machine(self, machine_id: str) -> Machine:
        with self.session() as session:
            return get_or_404(session, Machine, machine_id)

    def job(self, job_id: str, *, kind: str | None = None, field: str = "job_id") -> Job:
        """Another job's record; with ``kind``, it must be of that kind and have succeeded."""
        with self.session() as session:
            if kind is None:
                return get_or_404(session, Job, job_id, field=field)
            return succeeded_job(session, job_id, kind, field, error=ConformaError)

    def artifact_bytes(self, job_id: str, name: str) -> bytes:
        with self.session() as session:
            row = session.query(Artifact).filter(col(Artifact.job_id) == job_id,
                                                 col(Artifact.name) == name).one_or_none()
        if row is None:
            raise ConformaError(f"job {job_id!r} has no artifact {name!r}", field="artifact", value=name)
        return self.runtime.blobs.read(row.sha256)

    def artifacts_of(self, wanted: list[tuple[str, str]]) -> dict[tuple[str, str], Artifact]:
        """The artifact rows (job id, name) -> Artifact of ``wanted``, in one query per
        distinct job (not one per artifact: a board's children hold thousands); read their
        bytes with :meth:`blob`.  A missing one is a ConformaError naming it."""
        by_job: dict[str, set[str]] = {}
        for job_id, name in wanted:
            by_job.setdefault(job_id, set()).add(name)
        found: dict[tuple[str, str], Artifact] = {}
        with self.session() as session:
            for job_id, names in by_job.items():
                for row in session.exec(select(Artifact).where(Artifact.job_id == job_id)).all():
                    if row.name in names:
                        found[(job_id, row.name)] = row
        for job_id, name in wanted:
            if (job_id, name) not in found:
                raise ConformaError(f"job {job_id!r} has no artifact {name!r}", field="artifact", value=name)
        return found

    def blob(self, sha256: str) -> bytes:
        """Stored content by its sha256 (an artifact's :attr:`Artifact.sha256`)."""
        return self.runtime.blobs.read(sha256)

    def trace_names(self, trace_ids: list[str]) -> dict[str, str]:
        """trace id -> name, in one query (without the traces' nominal polylines)."""
        with self.session() as session:
            rows = session.exec(select(Trace.id, Trace.name).where(Trace.id.in_(trace_ids))).all()  # type: ignore[attr-defined]
        return dict(rows)

    def file_bytes(self, file_id: str, field: str = "file_id") -> bytes:
        """The content of an uploaded file (``POST /api/v1/files``)."""
        with self.session() as session:
            row = get_or_404(session, UploadedFile, file_id, field=field)
        return self.runtime.blobs.read(row.sha256)

    # outputs ---------------------------------------------------------------------
    def artifact(self, name: str, data: bytes, media_type: str, meta: dict[str, Any] | None = None) -> str:
        """Store an artifact of this job; returns its sha256."""
        with self.session() as session:
            artifact = add_artifact(session, self.runtime.blobs, self.job_id, name, data, media_type, meta)
            session.commit()
            return artifact.sha256

    def artifacts(self, items: list[tuple[str, bytes, str, dict[str, Any] | None]]) -> list[str]:
        """Store several artifacts of this job (name, data, media type, meta) in one commit
        (each blob written and fsynced before it; the rows an earlier attempt left under these
        names looked up in one query); their sha256 in order: all of them or none are listed."""
        names = [name for name, _, _, _ in items]
        with self.session() as session:
            existing = {row.name: row for row in session.exec(select(Artifact).where(
                Artifact.job_id == self.job_id, Artifact.name.in_(names))).all()}  # type: ignore[attr-defined]
            shas = self.runtime.blobs.put_many(session, [data for _, data, _, _ in items])
            new: dict[str, dict[str, Any]] = {}
            now = utcnow()
            for (name, data, media_type, meta), sha in zip(items, shas):
                row = existing.get(name)
                if row is not None:  # a retried attempt rewrites its artifact
                    row.sha256, row.bytes, row.media_type, row.meta = sha, len(data), media_type, meta or {}
                    session.add(row)
                else:  # the last of one name wins, as it would row by row
                    new[name] = {"job_id": self.job_id, "name": name, "created_at": now, "media_type": media_type,
                                 "bytes": len(data), "sha256": sha, "meta": meta or {}}
            if new:  # one statement for every new row (a board job stores hundreds at a time)
                session.connection().execute(_ARTIFACTS.insert(), list(new.values()))
            session.commit()
            return shas

    # children --------------------------------------------------------------------
    def submit_child(self, kind: str, params: dict[str, Any]) -> str:
        return self.runtime.submit(kind, params, parent_id=self.job_id).id

    def wait_for(self, job_ids: list[str], *, poll_s: float = 0.05) -> list[Job]:
        """Block until every job in ``job_ids`` is finished.  An operator's cancel of this job
        cancels them too; a lost lease does not (another attempt of this job takes over and
        reuses them: an interrupted child keeps its measured points for the operator's resume)."""
        while True:
            with self.session() as session:  # each poll reads the states only, not the results
                states = dict(session.exec(select(Job.id, Job.status).where(Job.id.in_(job_ids))).all())  # type: ignore[attr-defined]
                if all(states.get(job_id) in TERMINAL_STATES for job_id in job_ids):
                    jobs = {job.id: job for job in session.exec(select(Job).where(Job.id.in_(job_ids))).all()}  # type: ignore[attr-defined]
                    return [jobs[job_id] for job_id in job_ids]
            try:
                self.check_cancelled()
            except Cancelled:
                if not self.lost_event.is_set():
                    for job_id in job_ids:
                        self.runtime.store.request_cancel(job_id)
                raise
            time.sleep(poll_s)
