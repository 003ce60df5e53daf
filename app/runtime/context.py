"""What a running job sees: its parameters, progress reporting, cancel, inputs, artifacts.

Job kinds are thin adapters; everything they need from the service goes through this
object, so a kind never opens the database or the blob directory itself: stored records
through :meth:`JobContext.reads` (named queries, :class:`app.runtime.reads.JobReads`) and the
shortcuts below, live machines through :meth:`JobContext.lease` and
:meth:`JobContext.machine_world`, its program state through :meth:`JobContext.save_program_state`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import TYPE_CHECKING, Any

from sqlmodel import Session, select

from app.domain.errors import Cancelled, ConformaError
from app.platform.lookup import get_or_404
from app.platform.models import TERMINAL_STATES, Artifact, Job, Machine, Part, Trace, UploadedFile, utcnow
from app.runtime.reads import JobReads
from app.runtime.store import Claim

_ARTIFACTS = Artifact.__table__  # type: ignore[attr-defined]
WAIT_POLL_GROWTH = 1.5  # each wait for child jobs this many times the one before...
WAIT_POLL_MAX_S = 0.5  # ...up to this long (s): a finished child is seen within this

if TYPE_CHECKING:
    import trimesh

    from app.geometry.placement import Placement
    from app.runtime.engine import Runtime
    from hardware.mock import MockWorld


class JobContext:
    """The service side of one running attempt of one job."""

    def __init__(self, runtime: Runtime, claim: Claim) -> None:
        self.runtime = runtime
        self.claim = claim
        self.job_id = claim.job_id
        self.cancel_event = threading.Event()
        self.lost_event = threading.Event()
        # a runtime whose jobs' leases and cancels are watched from outside (a compute process:
        # its supervisor renews the lease and kills the process on a cancel) writes progress below
        # 1 at most this often, counted from the start: a job shorter than that writes none
        self.progress_every_s = float(getattr(runtime, "progress_every_s", 0.0))
        self._progress_at = time.monotonic()

    # progress and cancel ---------------------------------------------------------
    def progress(self, fraction: float, message: str | None = None) -> None:
        """Report progress (0..1); renews the lease.  Raises Cancelled when asked to stop.
        Where the runtime says so (``progress_every_s``), progress below 1 reported sooner than
        that after the last written is not written (progress 1, the closing words, always is)."""
        if self.progress_every_s > 0.0 and fraction < 1.0:
            now = time.monotonic()
            if now - self._progress_at < self.progress_every_s:
                self.check_cancelled()
                return
            self._progress_at = now
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
    def _session(self) -> Session:
        """A session of its own (kinds read through :meth:`reads`)."""
        return Session(self.runtime.engine, expire_on_commit=False)

    @contextmanager
    def reads(self) -> Iterator[JobReads]:
        """Named reads of stored records over one session (several queries, one snapshot)."""
        with self._session() as session:
            yield JobReads(session, read_blob=self.runtime.blobs.read)

    def part(self, part_id: str) -> Part:
        with self.reads() as reads:
            return reads.part(part_id)

    def mesh(self, part_id: str) -> trimesh.Trimesh:
        return self.runtime.meshes.mesh(self.part(part_id))

    def placed_mesh(self, part: Part, placement: Placement | None) -> trimesh.Trimesh:
        """The part's mesh in machine coordinates (as stored without a placement); cached."""
        return self.runtime.meshes.placed(part, placement)

    def trace(self, trace_id: str) -> Trace:
        with self.reads() as reads:
            return reads.trace(trace_id)

    def traces(self, trace_ids: list[str], *, nominals: bool = True) -> list[Trace]:
        """The traces ``trace_ids`` in order, read in one query (a board's thousand); a missing
        one is a NotFound naming it.  ``nominals=False``: without their nominal and source
        (reading one raises: :func:`app.jobs.inputs.placed_nominals` reads what it needs)."""
        with self.reads() as reads:
            return reads.traces(trace_ids, nominals=nominals)

    def trace_nominals(self, trace_ids: list[str]) -> dict[str, dict[str, Any]]:
        """trace id -> its stored nominal (the JSON), in one query."""
        with self.reads() as reads:
            return reads.trace_nominals(trace_ids)

    def machine(self, machine_id: str, field: str | None = None) -> Machine:
        with self.reads() as reads:
            return reads.machine(machine_id, field=field)

    def job(self, job_id: str, *, kind: str | None = None, field: str = "job_id") -> Job:
        """Another job's record; with ``kind``, it must be of that kind and have succeeded."""
        with self.reads() as reads:
            if kind is None:
                return reads.job(job_id, field=field)
            return reads.succeeded_job(job_id, kind, field, error=ConformaError)

    def require_succeeded(self, job_id: str, kind: str, field: str) -> None:
        """Raise (as :meth:`job` with ``kind``) unless ``job_id`` is a succeeded job of ``kind``;
        reads its kind and state only, not its record's result."""
        with self.reads() as reads:
            reads.require_succeeded(job_id, kind, field, error=ConformaError)

    def artifact_bytes(self, job_id: str, name: str) -> bytes:
        with self.reads() as reads:
            row = reads.artifact(job_id, name)
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
        with self._session() as session:
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
        with self.reads() as reads:
            return reads.trace_names(trace_ids)

    def file_bytes(self, file_id: str, field: str = "file_id") -> bytes:
        """The content of an uploaded file (``POST /api/v1/files``)."""
        with self._session() as session:
            row = get_or_404(session, UploadedFile, file_id, field=field)
        return self.runtime.blobs.read(row.sha256)

    @property
    def max_upload_bytes(self) -> int:
        """The largest upload the service accepts (bytes): what a file a job reads may hold."""
        return int(self.runtime.settings.max_upload_mb * 2**20)

    # machines and program state --------------------------------------------------
    def lease(self, machine_id: str) -> AbstractContextManager[None]:
        """Hold ``machine_id`` for this job while it moves it (one program per machine)."""
        return self.runtime.machines.lease(machine_id, self.job_id)

    def machine_world(self, machine: Machine) -> MockWorld | None:
        """The simulated world of the mock machine ``machine`` (what it deposited), None on
        real hardware."""
        return self.runtime.machines.world(machine)

    def save_program_state(self, state: dict[str, Any]) -> bool:
        """Record where this job's program stands (what a resume continues from)."""
        return self.runtime.store.save_program_state(self.claim, state)

    def wait_for_operator(self, state: dict[str, Any], message: str) -> bool:
        """End this attempt waiting at a pause point with ``state`` (False: the lease was lost)."""
        return self.runtime.store.wait(self.claim, state, message)

    # outputs ---------------------------------------------------------------------
    def artifact(self, name: str, data: bytes, media_type: str, meta: dict[str, Any] | None = None) -> str:
        """Store an artifact of this job; returns its sha256 (:meth:`artifacts` of one: its row
        written by one statement, not through the ORM's unit of work)."""
        return self.artifacts([(name, data, media_type, meta)])[0]

    def artifacts(self, items: list[tuple[str, bytes, str, dict[str, Any] | None]]) -> list[str]:
        """Store several artifacts of this job (name, data, media type, meta) in one commit
        (each blob on disk before it, a group's files flushed together; the rows an earlier attempt left under these
        names looked up in one query); their sha256 in order: all of them or none are listed."""
        names = [name for name, _, _, _ in items]
        with self._session() as session:
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

    def artifact_batch(self, max_bytes: int = 64 * 2**20) -> ArtifactBatch:
        """Artifacts stored together (:meth:`artifacts`: one commit for several files) while
        what waits is under ``max_bytes``; use it as a context manager (the rest is stored on exit)."""
        return ArtifactBatch(self, max_bytes)

    # children --------------------------------------------------------------------
    def submit_child(self, kind: str, params: dict[str, Any]) -> str:
        return self.runtime.submit(kind, params, parent_id=self.job_id).id

    def wait_for(self, job_ids: list[str], *, poll_s: float = 0.05, max_poll_s: float = WAIT_POLL_MAX_S) -> list[Job]:
        """Block until every job in ``job_ids`` is finished.  An operator's cancel of this job
        cancels them too; a lost lease does not (another attempt of this job takes over and
        reuses them: an interrupted child keeps its measured points for the operator's resume).
        The states are read ``poll_s`` after the first read, then each wait WAIT_POLL_GROWTH
        times the one before up to ``max_poll_s`` (a child of seconds is seen within a few
        tenths; one of minutes is not read twenty times a second, each read a query of this
        process's CPU)."""
        wait_s = poll_s
        while True:
            with self._session() as session:  # each poll reads the states only, not the results
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
            time.sleep(wait_s)
            wait_s = min(wait_s * WAIT_POLL_GROWTH, max(max_poll_s, poll_s))


class ArtifactBatch:
    """Artifacts of one job stored a few at a time: each :meth:`add` waits in memory until what
    waits reaches ``max_bytes`` (then all of it is stored in one commit, :meth:`JobContext.artifacts`),
    the rest on :meth:`flush` or at the end of the ``with`` block.  Small files cost one commit
    between them instead of one each; large ones are still let go one at a time.  The rows keep
    the order of the calls."""

    def __init__(self, ctx: JobContext, max_bytes: int) -> None:
        self.ctx = ctx
        self.max_bytes = max_bytes
        self.waiting: list[tuple[str, bytes, str, dict[str, Any] | None]] = []
        self.bytes = 0

    def add(self, name: str, data: bytes, media_type: str, meta: dict[str, Any] | None = None) -> None:
        """Store ``data`` as artifact ``name`` (now, or with the next ones)."""
        self.waiting.append((name, data, media_type, meta))
        self.bytes += len(data)
        if self.bytes >= self.max_bytes:
            self.flush()

    def flush(self) -> None:
        """Store what waits (one commit)."""
        if self.waiting:
            waiting, self.waiting, self.bytes = self.waiting, [], 0
            self.ctx.artifacts(waiting)

    def __enter__(self) -> ArtifactBatch:
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        if kind is None:  # a job that failed half way stores nothing more
            self.flush()
