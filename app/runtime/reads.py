"""The stored records a job kind reads, as named queries over one database session.

Job kinds and their shared helpers (``app/jobs``) never query the database themselves: at
submission the engine hands a kind's ``check`` and ``estimate`` a :class:`JobReads` over the
submission's session; when a job runs, :meth:`app.runtime.context.JobContext.reads` opens one.
A record looked up by id that does not exist is a :class:`app.domain.errors.NotFound` naming
``field``; the ``find_*`` variants answer None instead.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from datetime import datetime
from typing import Any, NamedTuple

from sqlalchemy.orm import defer
from sqlmodel import Session, col, select

from app.domain.errors import ConformaError, InvalidInput, NotFound
from app.platform.lookup import get_or_404
from app.platform.models import (
    Artifact,
    Blob,
    CircuitImport,
    Job,
    JobReference,
    Machine,
    Part,
    Program,
    Trace,
    UploadedFile,
)

#: a trace's columns a board job need not read with the rest: its draped nominal (~6 KB of JSON
#: each, most of a board's bytes, parsed once per process: :mod:`app.jobs.held_nominals`) and
#: its source
UNREAD_WITHOUT_NOMINALS = ("nominal", "source")


class TraceSummary(NamedTuple):
    """The columns of a trace the net checks read (not its geometry nor frame)."""

    id: str
    name: str
    source: dict[str, Any] | None
    width_mm: float | None
    nominal: dict[str, Any]


class FinishedJob(NamedTuple):
    """Id, kind, parameters and times of a succeeded job (not its result)."""

    id: str
    kind: str
    params: dict[str, Any]
    finished_at: datetime | None
    created_at: datetime


class JobReads:
    """Named reads over one open session.

    parent_id: the job whose child is being submitted (None: not a child); read_blob: the
    stored content by sha256 (None where stored files are not to be read); notes: what a
    kind's ``check`` leaves for its ``estimate`` of the same submission."""

    def __init__(self, session: Session, *, parent_id: str | None = None,
                 read_blob: Callable[[str], bytes] | None = None) -> None:
        self._session = session
        self.parent_id = parent_id
        self.read_blob = read_blob
        self.notes: dict[str, Any] = {}

    # records by id -------------------------------------------------------------------------
    def part(self, part_id: str, field: str | None = None) -> Part:
        return get_or_404(self._session, Part, part_id, field=field)

    def trace(self, trace_id: str, field: str | None = None) -> Trace:
        return get_or_404(self._session, Trace, trace_id, field=field)

    def machine(self, machine_id: str, field: str | None = None) -> Machine:
        return get_or_404(self._session, Machine, machine_id, field=field)

    def job(self, job_id: str, field: str | None = None) -> Job:
        return get_or_404(self._session, Job, job_id, field=field)

    def program(self, program_id: str, field: str | None = None) -> Program:
        return get_or_404(self._session, Program, program_id, field=field)

    def circuit_import(self, import_id: str, field: str | None = None) -> CircuitImport:
        return get_or_404(self._session, CircuitImport, import_id, field=field)

    def blob_bytes(self, sha256: str) -> int:
        """The size (bytes) of the stored content ``sha256`` (NotFound when it is not stored)."""
        return get_or_404(self._session, Blob, sha256).bytes

    # the ``find_*`` reads: None for a missing record (or no id)
    def find_part(self, part_id: str | None) -> Part | None:
        return None if part_id is None else self._session.get(Part, part_id)

    def find_trace(self, trace_id: str | None) -> Trace | None:
        return None if trace_id is None else self._session.get(Trace, trace_id)

    def find_machine(self, machine_id: str | None) -> Machine | None:
        return None if machine_id is None else self._session.get(Machine, machine_id)

    def find_job(self, job_id: str | None) -> Job | None:
        return None if job_id is None else self._session.get(Job, job_id)

    def find_upload(self, file_id: str | None) -> UploadedFile | None:
        return None if file_id is None else self._session.get(UploadedFile, file_id)

    def succeeded_job(self, job_id: str, kind: str | None, field: str, *,
                      error: type[ConformaError] = InvalidInput, missing_is_invalid: bool = False,
                      hint: str = "") -> Job:
        """The job ``job_id`` when it succeeded (and is of ``kind``, unless None).

        A missing job is a NotFound (404) naming ``field``, or with ``missing_is_invalid`` an
        ``error``; a job of another kind or state is an ``error`` (InvalidInput: 422) naming
        ``field`` and the job id; ``hint`` is appended to its message."""
        job = self._session.get(Job, job_id)
        _require_succeeded(job_id, None if job is None else (job.kind, job.status), kind, field, error=error,
                           missing_is_invalid=missing_is_invalid, hint=hint)
        assert job is not None
        return job

    def require_succeeded(self, job_id: str, kind: str | None, field: str, *,
                          error: type[ConformaError] = InvalidInput) -> None:
        """:meth:`succeeded_job`'s refusals, reading the job's kind and state only (not its result)."""
        state = self._session.exec(select(col(Job.kind), col(Job.status)).where(col(Job.id) == job_id)).first()
        _require_succeeded(job_id, None if state is None else (state[0], state[1]), kind, field, error=error)

    # traces ----------------------------------------------------------------------------------
    def traces(self, trace_ids: list[str], *, nominals: bool = True) -> list[Trace]:
        """The traces ``trace_ids`` in order, read in one query (a board's thousand); a missing
        one is a NotFound naming it.  ``nominals=False``: without their nominal and source
        (:data:`UNREAD_WITHOUT_NOMINALS`; reading one once the session has closed raises)."""
        rows = self.traces_by_id(trace_ids, nominals=nominals)
        missing = next((t for t in trace_ids if t not in rows), None)
        if missing is not None:
            raise NotFound(f"trace {missing!r} does not exist", field="trace_id", value=missing)
        return [rows[t] for t in trace_ids]

    def traces_by_id(self, trace_ids: Iterable[str], *, nominals: bool = True) -> dict[str, Trace]:
        """{id: trace} of those of ``trace_ids`` that exist, in one query (``nominals`` as
        for :meth:`traces`)."""
        query = select(Trace).where(col(Trace.id).in_(list(trace_ids)))
        if not nominals:
            query = query.options(*(defer(getattr(Trace, name)) for name in UNREAD_WITHOUT_NOMINALS))
        rows = self._session.exec(query).all()
        return {t.id: t for t in rows}

    def trace_nominals(self, trace_ids: list[str]) -> dict[str, dict[str, Any]]:
        """trace id -> its stored nominal (the JSON), in one query."""
        rows = self._session.exec(select(col(Trace.id), col(Trace.nominal)).where(col(Trace.id).in_(trace_ids))).all()
        return dict(rows)

    def traces_of_part(self, part_id: str) -> list[Trace]:
        """Every trace on ``part_id``, oldest first (ties by id)."""
        rows = self._session.exec(select(Trace).where(Trace.part_id == part_id)).all()
        return sorted(rows, key=lambda t: (t.created_at, t.id))

    def trace_names(self, trace_ids: list[str]) -> dict[str, str]:
        """trace id -> name, in one query (without the traces' nominal polylines)."""
        rows = self._session.exec(select(col(Trace.id), col(Trace.name)).where(col(Trace.id).in_(trace_ids))).all()
        return dict(rows)

    def trace_sources(self, trace_ids: list[str]) -> dict[str, dict[str, Any]]:
        """trace id -> its ``source`` (where it was imported from; empty when none), in one query."""
        rows = self._session.exec(select(col(Trace.id), col(Trace.source)).where(col(Trace.id).in_(trace_ids))).all()
        return {trace_id: source or {} for trace_id, source in rows}

    def trace_summaries(self, trace_ids: list[str]) -> list[TraceSummary]:
        """The :class:`TraceSummary` of those of ``trace_ids`` that exist, in one query."""
        rows = self._session.exec(select(  # type: ignore[call-overload]
            col(Trace.id), col(Trace.name), col(Trace.source), col(Trace.width_mm), col(Trace.nominal))
            .where(col(Trace.id).in_(trace_ids))).all()
        return [TraceSummary(*row) for row in rows]

    # artifacts -------------------------------------------------------------------------------
    def artifact(self, job_id: str, name: str) -> Artifact | None:
        """Job ``job_id``'s artifact ``name``, or None."""
        return self._session.exec(select(Artifact).where(Artifact.job_id == job_id, Artifact.name == name)).first()

    def artifact_shas(self, job_id: str) -> dict[str, str]:
        """{artifact name: sha256} of ``job_id``'s stored artifacts."""
        rows = self._session.exec(select(col(Artifact.name), col(Artifact.sha256)).where(
            Artifact.job_id == job_id)).all()
        return dict(rows)

    def artifact_names(self, job_id: str, names: list[str]) -> set[str]:
        """Which of ``names`` job ``job_id`` has stored as artifacts (one query)."""
        rows = self._session.exec(select(col(Artifact.name)).where(Artifact.job_id == job_id,
                                                                   col(Artifact.name).in_(names))).all()
        return set(rows)

    # jobs ------------------------------------------------------------------------------------
    def succeeded_children(self, parent_id: str) -> list[Job]:
        """The succeeded child jobs of ``parent_id``."""
        return list(self._session.exec(select(Job).where(Job.parent_id == parent_id,
                                                         Job.status == "succeeded")).all())

    def succeeded_on_machine(self, machine_id: str, kinds: tuple[str, ...]) -> list[FinishedJob]:
        """The succeeded jobs of ``kinds`` on ``machine_id`` (ids, parameters and times only)."""
        # sqlmodel types select() of up to four columns; this is five
        rows = self._session.exec(select(col(Job.id), col(Job.kind), col(Job.params),  # type: ignore[call-overload]
                                         col(Job.finished_at), col(Job.created_at)).where(
            col(Job.machine_id) == machine_id, col(Job.kind).in_(kinds), col(Job.status) == "succeeded")).all()
        return [FinishedJob(*row) for row in rows]

    def machine_holder(self, machine_id: str, kinds: tuple[str, ...]) -> dict[str, Any] | None:
        """A job of ``kinds`` referencing ``machine_id`` that is queued, running, interrupted
        or waiting, other than :attr:`parent_id` (``{"id", "kind", "status", "program_state"}``),
        or None."""
        query = (select(Job.id, col(Job.kind), col(Job.status), col(Job.program_state))
                 .join(JobReference, col(JobReference.job_id) == col(Job.id))
                 .where(JobReference.ref_kind == "machine", JobReference.ref_id == machine_id,
                        col(Job.status).in_(("queued", "running", "interrupted", "waiting")),
                        col(Job.kind).in_(kinds)))
        if self.parent_id is not None:
            query = query.where(Job.id != self.parent_id)
        busy = self._session.exec(query).first()
        if busy is None:
            return None
        return {"id": busy[0], "kind": busy[1], "status": busy[2], "program_state": busy[3]}


def _require_succeeded(job_id: str, state: tuple[str, str] | None, kind: str | None, field: str, *,
                       error: type[ConformaError], missing_is_invalid: bool = False, hint: str = "") -> None:
    """Raise unless ``state`` (the job's kind and status; None: no such job) is a succeeded job
    of ``kind`` (see :meth:`JobReads.succeeded_job`)."""
    needed = f"a succeeded {kind} job" if kind else "a succeeded job"
    if state is None:
        if missing_is_invalid:
            raise error(f"{field}: job {job_id!r} does not exist; {needed} is needed{hint}", field=field,
                        value=job_id)
        raise NotFound(f"job {job_id!r} does not exist", field=field, value=job_id)
    job_kind, status = state
    if status != "succeeded" or (kind is not None and job_kind != kind):
        raise error(f"job {job_id!r} is a {status} {job_kind} job; {needed} is needed{hint}", field=field,
                    value=job_id)
