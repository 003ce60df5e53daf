"""The job runtime: submission, dispatch through huey, execution, leases and the reaper.

One :class:`Runtime` per process.  The API process submits (and, by default, runs an
embedded consumer); ``conforma worker`` processes only consume.  The queue carries job ids
only; the job table decides who runs what (``JobStore``).  Queues: ``default`` for compute
jobs, ``machine`` for jobs that own a serial port (one worker thread, on the host that
owns the port) and ``workflow`` for parents that chain child jobs.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import socket
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from huey import RedisHuey, SqliteHuey
from huey.consumer import BaseProcess, Consumer, Worker
from huey.storage import SqliteStorage
from pydantic import ValidationError
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import defer
from sqlmodel import Session, col, select
from threadpoolctl import threadpool_limits

import app
from app.domain.errors import Cancelled, Conflict, ConformaError, InvalidInput, NotFound
from app.machines.live import MachineManager
from app.parts.meshes import MeshCache
from app.platform.blobs import BlobStore
from app.platform.config import Settings
from app.platform.db import existing_locked, make_engine
from app.platform.lookup import get_or_404
from app.platform.models import Job, JobReference, Part, Trace, new_id, utcnow
from app.platform.models import Machine as MachineRow
from app.platform.problems import _short, from_error, problem
from app.runtime.context import JobContext
from app.runtime.cost import check_cost
from app.runtime.heap import trim_heap
from app.runtime.machine_queue import MachineThreads, machine_slot
from app.runtime.process_worker import ProcessSupervisor, warm_up
from app.runtime.reads import UNREAD_WITHOUT_NOMINALS, JobReads
from app.runtime.registry import JobKind, get_kind, load_kinds
from app.runtime.store import JobStore, completed_status, encoded_result

log = logging.getLogger("conforma.jobs")
QUEUES = ("default", "machine", "workflow")
# Threads per queue: "machine" owns serial ports (one job at a time); "workflow" runs
# parents that only submit children and wait, so they never starve compute jobs.
_THREADS = {"machine": 1, "workflow": 2}
HEAP_TRIM_S = 10.0  # the reaper returns freed heap memory to the system this often (app.runtime.heap)


class _NormalSyncSqliteStorage(SqliteStorage):
    """SqliteHuey storage with WAL + synchronous=NORMAL (FIELD_NOTES: 60x faster than FULL)."""

    def _create_connection(self) -> sqlite3.Connection:
        conn = super()._create_connection()
        conn.execute("PRAGMA synchronous=NORMAL")
        return conn


class QueueWake:
    """Wakes a queue's idle consumer threads when this process enqueues onto it.

    A worker takes a ticket (the count of enqueues so far) before it reads the queue; if the
    queue was empty it sleeps until the count moves past its ticket (an enqueue it may have
    missed), the stop flag is set, or ``timeout_s`` passes (work enqueued by another process)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._count = 0
        self.wakeups = 0  # sleeps ended, for tests and measurements

    def ticket(self) -> int:
        with self._cond:
            return self._count

    def notify(self, everyone: bool = False) -> None:
        """One more job on the queue: wake one sleeping worker (``everyone``: all, to stop)."""
        with self._cond:
            self._count += 1
            if everyone:
                self._cond.notify_all()
            else:
                self._cond.notify()

    def wait(self, ticket: int, timeout_s: float, stop: threading.Event) -> None:
        with self._cond:
            self._cond.wait_for(lambda: self._count != ticket or stop.is_set(), timeout_s)
            self.wakeups += 1


class _WakeableWorker(Worker):
    """A huey worker that sleeps on its queue's :class:`QueueWake` instead of polling."""

    wake: QueueWake
    _ticket = 0

    def loop(self, now: Any = None) -> None:
        self._ticket = self.wake.ticket()
        super().loop(now)

    def sleep(self) -> None:
        self.wake.wait(self._ticket, self.max_delay, self.stop_flag)


class _NoScheduler(BaseProcess):
    """The consumer's scheduler, idle: jobs are never scheduled for later (no huey retries or
    ETAs), so reading the schedule every second would be wasted work."""

    def loop(self, now: Any = None) -> None:
        self.stop_flag.wait(3600.0)


class _EmbeddedConsumer(Consumer):
    """A huey consumer that can run in a non-main thread (no signal handlers), whose workers
    sleep until this process enqueues (or the fallback poll ``max_delay`` passes)."""

    def __init__(self, huey: Any, wake: QueueWake, **options: Any) -> None:
        self.wake = wake  # before the base class creates the workers
        super().__init__(huey, **options)

    def _create_worker(self) -> Worker:
        worker = _WakeableWorker(huey=self.huey, stop_flag=self.stop_flag, default_delay=self.max_delay,
                                 max_delay=self.max_delay, backoff=1.0)
        worker.wake = self.wake
        return worker

    def _create_scheduler(self) -> BaseProcess:
        return _NoScheduler(self.huey, self.stop_flag)

    def _set_signal_handlers(self) -> None:
        return None


def make_queue(settings: Settings, queue: str) -> Any:
    """The huey instance of ``queue`` (SqliteHuey under data_dir, or RedisHuey)."""
    name = f"conforma-{queue}"
    if settings.queue_url:
        return RedisHuey(name=name, url=settings.queue_url, blocking=True, read_timeout=1, results=False)
    settings.data_dir.mkdir(parents=True, exist_ok=True)

    class _Huey(SqliteHuey):
        storage_class = _NormalSyncSqliteStorage

    return _Huey(name=name, filename=str(settings.data_dir / "queue.db"), results=False)


def _param_holding(params: Any, value: str, ref_kind: str) -> str:
    """The dotted path of the parameter whose value is ``value`` (searched through nested
    lists and objects, e.g. ``context.1.trace_id``), for error messages."""

    def find(given: Any, path: str) -> str | None:
        if given == value:
            return path
        items = given.items() if isinstance(given, dict) else (
            enumerate(given) if isinstance(given, list) else ())
        for key, inner in items:
            found = find(inner, f"{path}.{key}" if path else str(key))
            if found is not None:
                return found
        return None

    return find(params.model_dump(), "") or f"{ref_kind}_id"


_REFERENCED: dict[str, type[Part] | type[Trace] | type[Job] | type[MachineRow]] = {
    "part": Part, "trace": Trace, "job": Job, "machine": MachineRow}


def _by_model(references: list[tuple[str, str]]) -> dict[Any, list[str]]:
    """The referenced record ids grouped by their table (references to no table left out)."""
    out: dict[Any, list[str]] = {}
    for ref_kind, ref_id in references:
        model = _REFERENCED.get(ref_kind)
        if model is not None:
            out.setdefault(model, []).append(ref_id)
    return out


#: columns a submission's checks and input hashes never read, left unread when the referenced
#: records are read together
_UNREAD_AT_SUBMISSION: dict[type, tuple[str, ...]] = {Trace: UNREAD_WITHOUT_NOMINALS}


def _preload(session: Session, references: list[tuple[str, str]]) -> list[Any]:
    """Read every referenced record in one query per table (a board loop references thousands
    of traces), so that the checks' ``session.get`` of each finds it in the session; the
    records are returned to be held (the session keeps them only while they are referenced).
    The columns of :data:`_UNREAD_AT_SUBMISSION` are deferred: a check that reads one loads it."""
    held: list[Any] = []
    for model, ids in _by_model(references).items():
        if len(ids) > 1:
            unread = [defer(getattr(model, name)) for name in _UNREAD_AT_SUBMISSION.get(model, ())]
            held += session.exec(select(model).where(col(model.id).in_(ids)).options(*unread)).all()
    return held


def _recheck_references(session: Session, references: list[tuple[str, str]], validated: Any) -> None:
    """After the job's rows are written (the transaction holds the write lock): every
    referenced record still exists, else NotFound naming the parameter (rolled back); one
    locked read per table."""
    present = {model: existing_locked(session, model, ids) for model, ids in _by_model(references).items()}
    for ref_kind, ref_id in references:
        model = _REFERENCED.get(ref_kind)
        if model is not None and ref_id not in present[model]:
            raise NotFound(f"{ref_kind} {ref_id!r} was deleted while the job was being submitted",
                           field=f"params.{_param_holding(validated, ref_id, ref_kind)}", value=ref_id)


def _canonical_hash(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()


def linuxcnc_options(settings: Settings) -> dict[str, str]:
    """``LinuxCNCMachine`` keyword arguments from the ``CONFORMA_LINUXCNC_*`` settings (the
    ones set: the others fall back to the environment, then to LinuxCNC's defaults)."""
    given = {"connect_pw": settings.linuxcnc_connectpw, "enable_pw": settings.linuxcnc_enablepw,
             "program_dir": str(settings.linuxcnc_programs) if settings.linuxcnc_programs else None,
             "hal_prefix": settings.linuxcnc_hal_prefix}
    return {name: value for name, value in given.items() if value is not None}


class Runtime:
    """Engine, blobs, queues and workers of one process."""

    def __init__(self, settings: Settings, engine: Any | None = None) -> None:
        self.settings = settings
        self.engine = engine or make_engine(settings)
        self.blobs = BlobStore(settings.blob_dir)
        self.meshes = MeshCache(self.blobs)
        self.store = JobStore(self.engine, settings.lease_s)
        self.machines = MachineManager(self._part_mesh, linuxcnc=linuxcnc_options(settings))
        self.worker_id = f"{socket.gethostname()}:{os.getpid()}"
        self.kinds = load_kinds(settings.job_plugins.split(","))
        self.queues = {name: make_queue(settings, name) for name in QUEUES}
        self.machine_threads = MachineThreads(self)  # one execution thread per machine
        self.tasks = {name: huey.task(name="run_job")(self.machine_threads.dispatch if name == "machine"
                                                      else self.execute)
                      for name, huey in self.queues.items()}
        self.wakes = {name: QueueWake() for name in QUEUES}
        self._consumers: list[Consumer] = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.supervisor = ProcessSupervisor(self)

    @contextmanager
    def reads(self) -> Iterator[JobReads]:
        """Named reads of stored records over one session (for what acts on jobs from outside
        a running one, e.g. an operator's decision on a waiting loop)."""
        with Session(self.engine, expire_on_commit=False) as session:
            yield JobReads(session, read_blob=self.blobs.read)

    def _part_mesh(self, part_id: str) -> Any:
        with Session(self.engine) as session:
            return self.meshes.mesh(get_or_404(session, Part, part_id))

    # submission ------------------------------------------------------------------
    def validate(self, kind_name: str, params: dict[str, Any]) -> tuple[JobKind, Any]:
        """The kind and its validated parameters, or an InvalidInput naming the field."""
        kind = get_kind(kind_name)
        if kind is None:
            raise InvalidInput(
                f"unknown job kind {kind_name!r}; known kinds: {', '.join(sorted(self.kinds))}",
                field="kind", value=kind_name,
            )
        try:
            validated = kind.params.model_validate(params)
        except ValidationError as exc:
            first = exc.errors()[0]
            loc = ".".join(str(p) for p in ("params", *first["loc"]))
            given = "input" in first and first["type"] != "missing"  # the bad value, as the API's 422 says it
            got = f" (got {_short(first['input'])!r})" if given else ""
            raise InvalidInput(f"{loc}: {first['msg']}{got}", field=loc, value=first.get("input")) from None
        return kind, validated

    def submit(self, kind_name: str, params: dict[str, Any], *, parent_id: str | None = None,
               before_commit: Callable[[Session, Job], None] | None = None) -> Job:
        """Validate, record (with input hashes) and enqueue a job.  Raises before writing on bad input.

        The references are checked again under a lock after the job is written, so a record
        deleted meanwhile is a 404 naming it and never a job pointing at nothing.
        ``before_commit(session, job)`` may add rows to the job's transaction (the API's
        idempotency record)."""
        kind, validated = self.validate(kind_name, params)
        references = kind.references(validated)
        with Session(self.engine, expire_on_commit=False) as session:
            hashes: dict[str, str] = {}
            held = _preload(session, references)  # noqa: F841 (held while the checks read them)
            for ref_kind, ref_id in references:
                model = _REFERENCED.get(ref_kind)
                if model is None:
                    continue
                try:
                    record = get_or_404(session, model, ref_id)
                except NotFound as exc:
                    raise InvalidInput(exc.message, field=f"params.{_param_holding(validated, ref_id, ref_kind)}",
                                       value=ref_id) from None
                if isinstance(record, Part):
                    hashes[f"part:{ref_id}"] = record.sha256
                elif isinstance(record, Trace):
                    hashes[f"trace:{ref_id}"] = _canonical_hash([record.geometry, record.frame, record.standoff_mm])
            # checks may need to know whose child this is, and to read stored files
            reads = JobReads(session, parent_id=parent_id, read_blob=self.blobs.read)
            if kind.check is not None:
                kind.check(validated, reads)
            check_cost(kind, validated, reads, self.settings)  # hopeless parameters: 422 naming them
            job = Job(
                id=new_id("job"), kind=kind.name, params=validated.model_dump(mode="json"),
                parent_id=parent_id, queue=kind.queue, max_attempts=self.settings.max_attempts,
                input_hashes=hashes, software_version=app.__version__, created_at=utcnow(),
                machine_id=(slot := machine_slot(kind.name, validated.model_dump(mode="json"))),
            )
            session.add(job)
            try:
                session.flush()
                for ref_kind, ref_id in dict.fromkeys(references):
                    session.add(JobReference(job_id=job.id, ref_kind=ref_kind, ref_id=ref_id))
                session.flush()
                _recheck_references(session, references, validated)
                if before_commit is not None:
                    before_commit(session, job)
                session.commit()
            except IntegrityError as exc:  # the unique index: another program holds the machine
                session.rollback()
                if slot is None or not any(n in str(exc.orig) for n in ("jobs.machine_id", "uq_jobs_active_machine")):
                    raise
                raise Conflict(f"machine {slot!r} already has a program queued, running or interrupted; "
                               "one program at a time", field="params.machine_id", value=slot) from exc
        self.enqueue(job.id, job.queue)
        return job

    def enqueue(self, job_id: str, queue: str = "default") -> None:
        queue = queue if queue in self.tasks else "default"
        try:
            self.tasks[queue](job_id)
            self.wakes[queue].notify()  # this process's idle worker starts it now
            self.store.mark_enqueued(job_id)
        except Exception:  # the reaper enqueues it again later
            log.exception("could not enqueue job %s", job_id)

    # execution -------------------------------------------------------------------
    def execute(self, job_id: str) -> None:
        """Run one job if it can be claimed (the huey task body)."""
        claim = self.store.claim(job_id, f"{self.worker_id}:{threading.get_ident()}")
        if claim is None:
            return
        kind = get_kind(claim.kind)
        if kind is None:
            self.store.finish(claim, "failed", error=problem(422, "Unknown job kind", f"no worker kind {claim.kind!r}"))
            return
        if kind.queue == "default" and self.settings.compute_isolation == "process":
            self.supervisor.run(claim)  # in a child process: memory/time limits, hard cancel
            return
        ctx = JobContext(self, claim)
        done = threading.Event()
        threading.Thread(target=self._heartbeat, args=(ctx, done), daemon=True, name=f"lease-{job_id}").start()
        try:
            params = kind.params.model_validate(claim.params)
            result, size = encoded_result(kind.run(ctx, params))
            self.store.finish(claim, completed_status(result), result=result, result_bytes=size)
        except Cancelled as exc:
            self.store.finish(claim, "cancelled", error=from_error(exc))
        except ConformaError as exc:
            self.store.finish(claim, "failed", error=from_error(exc))
        except Exception as exc:  # a bug: record it without a stack trace for clients
            log.exception("job %s (%s) crashed", job_id, claim.kind)
            self.store.finish(claim, "failed", error=problem(500, "Job crashed", f"{type(exc).__name__}: {exc}"[:500]))
        finally:
            done.set()

    def _heartbeat(self, ctx: JobContext, done: threading.Event) -> None:
        """Renew the lease every third of it until ``done``; note cancel requests and a lost lease."""
        while not done.wait(self.settings.lease_s / 3):
            answer = self.store.heartbeat(ctx.claim)
            if answer is None:
                ctx.lost_event.set()
                return
            if answer:
                ctx.cancel_event.set()

    # workers and reaper ----------------------------------------------------------
    def start_workers(self, queues: tuple[str, ...] = QUEUES) -> None:
        """Start consumer threads for ``queues`` plus the reaper (idempotent per process)."""
        if "default" in queues and self.settings.compute_isolation == "process":
            if self.settings.compute_warm_up:
                threading.Thread(target=warm_up, args=(self.supervisor.pool,), daemon=True,
                                 name="compute-warm-up").start()
        elif "default" in queues:  # compute jobs in this process's threads: its BLAS limit, set once here
            threadpool_limits(limits=self.settings.blas_threads)
        for name in queues:
            threads = _THREADS.get(name, self.settings.worker_threads)
            consumer = _EmbeddedConsumer(self.queues[name], self.wakes[name], workers=threads, worker_type="thread",
                                         periodic=False, max_delay=self.settings.queue_poll_s,
                                         check_worker_health=False)
            consumer.start()
            self._consumers.append(consumer)
        if "machine" in queues:  # this process owns the machines: an earlier one's jobs are orphans
            self.store.interrupt_orphans(f"{self.worker_id}:")
        reaper = threading.Thread(target=self._reap_forever, daemon=True, name="reaper")
        reaper.start()
        self._threads.append(reaper)

    def reap_once(self) -> list[str]:
        stale_s = max(2 * self.settings.lease_s, 5.0)
        if not self.store.reap_due(stale_s):  # the usual pass: one read, no writes
            return []
        for job_id in self.store.quarantine_lost_compute_jobs():
            log.warning("job %s quarantined: its worker was lost twice while running it", job_id)
        ids = self.store.reap(stale_enqueue_s=stale_s)
        for job_id in ids:
            with Session(self.engine) as session:
                job = session.get(Job, job_id)
            if job is not None:
                self.enqueue(job_id, job.queue)
        return ids

    def _reap_forever(self) -> None:
        trimmed = time.monotonic()
        while not self._stop.wait(self.settings.reaper_interval_s):
            try:
                self.reap_once()
            except Exception:
                log.exception("reaper pass failed")
            if time.monotonic() - trimmed >= HEAP_TRIM_S:  # what requests and jobs freed goes back to the system
                trim_heap()
                trimmed = time.monotonic()

    def stop(self) -> None:
        self._stop.set()
        self.supervisor.stop()  # kills running compute children; their jobs go back to the queue
        self.machines.close_all()
        self.machine_threads.shutdown()
        for consumer in self._consumers:
            consumer.stop(graceful=False)
        for wake in self.wakes.values():
            wake.notify(everyone=True)  # sleeping workers see the stop flag now
        self._consumers.clear()
        for huey in self.queues.values():
            try:
                huey.storage.close()
            except Exception:
                pass
        self.engine.dispose()

