"""Job state transitions, each one conditional ``UPDATE ... WHERE ... RETURNING``.

The job table is the source of truth; the queue only carries job ids (at most once).
A worker owns a running job while ``worker`` and ``attempts`` match what it claimed and
its lease has not been taken away by the reaper.  Every change bumps ``revision`` so
that watchers (SSE) can tell that something changed.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import ColumnElement, Engine, Executable, and_, bindparam, case, literal, or_, select, update
from sqlalchemy.exc import DBAPIError
from sqlmodel import col

from app.jobs.results.models import result_summary
from app.platform.models import ATTENTION_KEY, COMPLETED_STATES, TERMINAL_STATES, Job, utcnow

FINISH_TRIES = 6  # JobStore.finish_surely: tries of an outcome's write...
FINISH_WAIT_S = 0.5  # ...this far apart, doubling (~16 s in all)
# Jobs that move a machine: when their process dies or their link drops they become
# ``interrupted`` and wait for an operator (never requeued by the reaper).
# One read, built once: is there anything for a reaper pass to do (a running job whose lease
# expired, a queued one whose enqueue is stale)?  Most passes find nothing, and their five
# conditional UPDATEs would each take the database's write lock for nothing.
_REAP_DUE = select(col(Job.id)).where(or_(
    and_(col(Job.status) == "running", col(Job.lease_until) < bindparam("now")),
    and_(col(Job.status) == "queued", col(Job.cancel_requested).is_(False),
         or_(col(Job.enqueued_at).is_(None), col(Job.enqueued_at) < bindparam("stale_before"))))).limit(1)

OPERATOR_RESUMED_KINDS = ("print", "probe_run", "register", "closed_loop", "calibrate_probe", "calibrate_nozzle",
                          "scan_run", "calibrate_sensor", "jetting_run")


@dataclass(frozen=True)
class Claim:
    """What a worker holds while it runs a job."""

    job_id: str
    kind: str
    worker: str
    attempt: int
    params: dict[str, Any]
    # the process that ran an earlier attempt, as recorded (app.runtime.process_identity)
    earlier_process: dict[str, Any] | None = None


class JobStore:
    """Conditional state changes on the jobs table."""

    def __init__(self, engine: Engine, lease_s: float) -> None:
        self.engine = engine
        self.lease_s = lease_s

    def _run(self, statement: Executable) -> Sequence[Any]:
        with self.engine.begin() as conn:
            result = conn.execute(statement)
            return result.fetchall() if result.returns_rows else []

    def mark_enqueued(self, job_id: str) -> None:
        self._run(update(Job).where(col(Job.id) == job_id).values(enqueued_at=time.time()))

    def claim(self, job_id: str, worker: str) -> Claim | None:
        """queued -> running for ``worker``; None if someone else has it or it was cancelled."""
        rows = self._run(
            update(Job)
            .where(and_(col(Job.id) == job_id, col(Job.status) == "queued", col(Job.cancel_requested).is_(False)))
            .values(
                status="running",
                attempts=col(Job.attempts) + 1,
                worker=worker,
                lease_until=time.time() + self.lease_s,
                started_at=utcnow(),
                revision=col(Job.revision) + 1,
            )
            .returning(col(Job.kind), col(Job.attempts), col(Job.params), col(Job.process))
        )
        if not rows:
            return None
        kind, attempt, params, process = rows[0]
        return Claim(job_id, kind, worker, attempt, dict(params), process if isinstance(process, dict) else None)

    def _owned(self, claim: Claim) -> ColumnElement[bool]:
        return and_(
            col(Job.id) == claim.job_id,
            col(Job.status) == "running",
            col(Job.worker) == claim.worker,
            col(Job.attempts) == claim.attempt,
        )

    def heartbeat(self, claim: Claim, progress: float | None = None, message: str | None = None) -> bool | None:
        """Renew the lease (and report progress).  Returns ``cancel_requested``, or None if lost."""
        values: dict[str, Any] = {"lease_until": time.time() + self.lease_s}
        if progress is not None:
            values["progress"] = min(max(float(progress), 0.0), 1.0)
            values["revision"] = col(Job.revision) + 1
        if message is not None:
            values["message"] = message[:500]
            values["revision"] = col(Job.revision) + 1
        rows = self._run(update(Job).where(self._owned(claim)).values(**values).returning(col(Job.cancel_requested)))
        return bool(rows[0][0]) if rows else None

    def finish(self, claim: Claim, status: str, *, result: dict | None = None, error: dict | None = None,
               result_bytes: int | None = None) -> bool:
        """running -> succeeded/needs_attention/failed/cancelled, only while ``claim`` still
        owns the job (``result_bytes``: the size of ``result``'s JSON when the caller encoded
        it already, :func:`encoded_result`; else it is encoded here to be measured)."""
        assert status in TERMINAL_STATES
        if result is not None and result_bytes is None:
            result_bytes = len(json.dumps(result).encode())
        values: dict[str, Any] = {
            "status": status,
            "result": result,
            "result_bytes": None if result is None else result_bytes,
            "result_summary": result_summary(claim.kind, result),
            "error": error,
            "finished_at": utcnow(),
            "lease_until": None,
            "revision": col(Job.revision) + 1,
        }
        if status in COMPLETED_STATES:
            values["progress"] = 1.0
        values["message"] = final_message(status, error)
        rows = self._run(update(Job).where(self._owned(claim)).values(**values).returning(col(Job.id)))
        return bool(rows)

    def finish_surely(self, claim: Claim, status: str, *, error: dict | None = None,
                      tries: int = FINISH_TRIES, wait_s: float = FINISH_WAIT_S) -> bool:
        """:meth:`finish`, tried again (``tries`` times, ``wait_s`` apart, doubling) while the
        database refuses the write (locked, a dropped connection): an outcome the process
        knows (out of memory, killed, timed out) is recorded, never left to the lease's expiry,
        which would run the job again without a word.  Raises the last error when every try
        failed."""
        for attempt in range(tries):
            try:
                return self.finish(claim, status, error=error)
            except DBAPIError:
                if attempt == tries - 1:
                    raise
                time.sleep(wait_s * 2 ** attempt)
        return False

    def request_cancel(self, job_id: str) -> str | None:
        """Ask a job to stop.  A queued job is cancelled at once; a running one cooperatively.

        Returns the status after the request, or None when the job is already finished
        (or a cancel was already requested for it).
        """
        rows = self._run(
            update(Job)
            .where(and_(col(Job.id) == job_id, col(Job.status).in_(("queued", "running")),
                        col(Job.cancel_requested).is_(False)))
            .values(cancel_requested=True, revision=col(Job.revision) + 1)
            .returning(col(Job.status))
        )
        if not rows:
            return self.abandon(job_id)
        self._run(
            update(Job)
            .where(and_(col(Job.id) == job_id, col(Job.status) == "queued"))
            .values(status="cancelled", finished_at=utcnow(), message="cancelled before start",
                    revision=col(Job.revision) + 1)
        )
        return "cancelled" if rows[0][0] == "queued" else "running"

    def reap_due(self, stale_enqueue_s: float) -> bool:
        """Whether :meth:`quarantine_lost_compute_jobs` or :meth:`reap` has anything to do now
        (one read, no write lock)."""
        now = time.time()
        with self.engine.connect() as conn:
            return conn.execute(_REAP_DUE, {"now": now, "stale_before": now - stale_enqueue_s}).first() is not None

    def reap(self, stale_enqueue_s: float) -> list[str]:
        """Requeue jobs whose lease expired (attempts left) and fail the rest.

        Also returns queued jobs whose enqueue is older than ``stale_enqueue_s`` (their queue
        message may have been lost with a crashed process); enqueueing them again is safe
        because :meth:`claim` is conditional.  Returns the ids to (re)enqueue.
        """
        now = time.time()
        expired = and_(col(Job.status) == "running", col(Job.lease_until) < now)
        self._run(
            update(Job)
            .where(and_(expired, col(Job.kind).in_(OPERATOR_RESUMED_KINDS)))
            .values(status="interrupted", lease_until=None, worker=None, revision=col(Job.revision) + 1,
                    message="interrupted: its process stopped reporting; resume or abandon it")
        )
        requeued = self._requeue_lost(
            and_(expired, col(Job.attempts) < col(Job.max_attempts), col(Job.cancel_requested).is_(False)), now)
        self._run(
            update(Job)
            .where(and_(expired, or_(col(Job.attempts) >= col(Job.max_attempts), col(Job.cancel_requested).is_(True))))
            .values(
                status="failed",
                finished_at=utcnow(),
                lease_until=None,
                revision=col(Job.revision) + 1, message="failed: the worker stopped reporting and no attempts are left",
                error={"type": "about:blank#lease-expired", "title": "Worker lost", "status": 500,
                       "detail": "the worker stopped reporting and no attempts are left"},
            )
        )
        stale = self._run(
            update(Job)
            .where(and_(col(Job.status) == "queued", col(Job.cancel_requested).is_(False),
                        or_(col(Job.enqueued_at).is_(None), col(Job.enqueued_at) < now - stale_enqueue_s)))
            .values(enqueued_at=now)
            .returning(col(Job.id))
        )
        return [r[0] for r in requeued] + [r[0] for r in stale]

    def status(self, job_id: str) -> tuple[str, int] | None:
        rows = self._run(select(col(Job.status), col(Job.revision)).where(col(Job.id) == job_id))
        return (rows[0][0], rows[0][1]) if rows else None

    # machine jobs: program state, interruption, resume ------------------------------
    def save_program_state(self, claim: Claim, state: dict[str, Any]) -> bool:
        """Record where the program stands (while ``claim`` owns the job)."""
        return bool(self._run(update(Job).where(self._owned(claim)).values(program_state=state).returning(col(Job.id))))

    def interrupt(self, claim: Claim, state: dict[str, Any], message: str) -> bool:
        """running -> interrupted: the job stops and waits for an operator's resume or
        abandon; ``state`` says where the program stands."""
        rows = self._run(
            update(Job).where(self._owned(claim))
            .values(status="interrupted", program_state=state, message=message[:500], lease_until=None,
                    worker=None, revision=col(Job.revision) + 1)
            .returning(col(Job.id)))
        return bool(rows)

    def interrupt_orphans(self, worker_prefix: str) -> list[str]:
        """At start-up of the process that owns the machines: machine jobs still marked
        running by an earlier process (it died), or queued before this process started
        (an operator asked then, not now), become interrupted at once."""
        rows = self._run(
            update(Job)
            .where(and_(col(Job.status) == "running", col(Job.kind).in_(OPERATOR_RESUMED_KINDS),
                        or_(col(Job.worker).is_(None), ~col(Job.worker).startswith(worker_prefix))))
            .values(status="interrupted", lease_until=None, worker=None, revision=col(Job.revision) + 1,
                    message="interrupted: the server stopped while it ran; resume or abandon it")
            .returning(col(Job.id)))
        waiting = self._run(
            update(Job)
            .where(and_(col(Job.status) == "queued", col(Job.kind).in_(OPERATOR_RESUMED_KINDS)))
            .values(status="interrupted", revision=col(Job.revision) + 1,
                    message="interrupted: the server restarted before it started; resume or abandon it")
            .returning(col(Job.id)))
        return [r[0] for r in rows] + [r[0] for r in waiting]

    def resume(self, job_id: str, state: dict[str, Any], revision: int) -> bool:
        """interrupted -> queued with ``state`` (carrying the operator's resume request),
        only if nobody changed the job since ``revision`` was read."""
        rows = self._run(
            update(Job)
            .where(and_(col(Job.id) == job_id, col(Job.status) == "interrupted", col(Job.revision) == revision))
            .values(status="queued", program_state=state, cancel_requested=False, enqueued_at=time.time(),
                    message="resume requested by an operator", revision=col(Job.revision) + 1)
            .returning(col(Job.id)))
        return bool(rows)

    def abandon(self, job_id: str) -> str | None:
        """interrupted or waiting -> cancelled (the operator gives the program up); None otherwise."""
        rows = self._run(
            update(Job)
            .where(and_(col(Job.id) == job_id, col(Job.status).in_(("interrupted", "waiting"))))
            .values(status="cancelled", finished_at=utcnow(), message="abandoned by an operator",
                    revision=col(Job.revision) + 1)
            .returning(col(Job.id)))
        return "cancelled" if rows else None

    # workflows: pause points (app.jobs.loop_gates) ----------------------------------
    def wait(self, claim: Claim, state: dict[str, Any], message: str) -> bool:
        """running -> waiting (while ``claim`` owns the job): the attempt ends at a pause point
        and holds no worker; ``state`` says where it waits.  A pause is not a failed attempt
        (``attempts`` is given back)."""
        rows = self._run(
            update(Job).where(self._owned(claim))
            .values(status="waiting", program_state=state, message=message[:500], lease_until=None, worker=None,
                    attempts=col(Job.attempts) - 1, revision=col(Job.revision) + 1)
            .returning(col(Job.id)))
        return bool(rows)

    def proceed(self, job_id: str, state: dict[str, Any], revision: int, message: str,
                from_states: tuple[str, ...] = ("waiting",)) -> bool:
        """waiting (or another of ``from_states``) -> queued with ``state`` (the operator's
        decision), only if nobody changed the job since ``revision`` was read."""
        rows = self._run(
            update(Job)
            .where(and_(col(Job.id) == job_id, col(Job.status).in_(from_states), col(Job.revision) == revision))
            .values(status="queued", program_state=state, cancel_requested=False, enqueued_at=time.time(),
                    finished_at=None, error=None, message=message[:500], revision=col(Job.revision) + 1)
            .returning(col(Job.id)))
        return bool(rows)

    def cancel_requested(self, job_id: str) -> bool:
        rows = self._run(select(col(Job.cancel_requested)).where(col(Job.id) == job_id))
        return bool(rows and rows[0][0])

    def machine_of(self, job_id: str) -> str | None:
        rows = self._run(select(col(Job.machine_id)).where(col(Job.id) == job_id))
        return rows[0][0] if rows else None

    def holding_job(self, machine_id: str) -> dict | None:
        """The machine job that holds ``machine_id`` (queued, running or interrupted: at
        most one, the unique index), as ``{"id", "kind", "status", "program_state"}``; None
        when the machine is free."""
        rows = self._run(select(col(Job.id), col(Job.kind), col(Job.status), col(Job.program_state)).where(and_(
            col(Job.machine_id) == machine_id, col(Job.status).in_(("queued", "running", "interrupted")))))
        if not rows:
            return None
        job_id, kind, status, state = rows[0]
        return {"id": job_id, "kind": kind, "status": status, "program_state": state}

    def jobs_on_machine(self, machine_id: str, statuses: tuple[str, ...]) -> list[str]:
        rows = self._run(select(col(Job.id)).where(and_(col(Job.machine_id) == machine_id,
                                                        col(Job.status).in_(statuses))))
        return [r[0] for r in rows]

    # compute jobs in processes (app.runtime.process_worker) ---------------------------------
    def release(self, claim: Claim, message: str) -> bool:
        """running -> queued for a job whose worker stops (not a crash): it runs again later."""
        rows = self._run(
            update(Job).where(self._owned(claim))
            .values(status="queued", worker=None, lease_until=None, enqueued_at=None, message=message[:500],
                    attempts=col(Job.attempts) - 1, revision=col(Job.revision) + 1)
            .returning(col(Job.id)))
        return bool(rows)

    def record_process(self, claim: Claim, process: dict[str, Any] | None) -> bool:
        """The process that runs ``claim``'s attempt (while ``claim`` owns the job)."""
        return bool(self._run(update(Job).where(self._owned(claim)).values(process=process).returning(col(Job.id))))

    def _requeue_lost(self, due: ColumnElement[bool], now: float) -> list[tuple[str]]:
        """running -> queued for each job ``due`` (its lease expired, attempts left), its
        ``earlier_attempts`` told why the attempt ended (a job run again is never run again
        silently); one transaction, each row conditional on ``due`` still holding.  Returns
        [(id,), ...] of the jobs requeued."""
        with self.engine.begin() as conn:
            rows = conn.execute(select(col(Job.id), col(Job.attempts), col(Job.earlier_attempts)).where(due)).fetchall()
            requeued: list[tuple[str]] = []
            for job_id, attempt, earlier in rows:
                entry = {"attempt": attempt, "ended_at": utcnow().isoformat(), "reason": LOST_LEASE_REASON}
                done = conn.execute(
                    update(Job).where(and_(col(Job.id) == job_id, due))
                    .values(status="queued", worker=None, lease_until=None, enqueued_at=now,
                            message="requeued after lost lease", revision=col(Job.revision) + 1,
                            earlier_attempts=[*(earlier or []), entry])
                    .returning(col(Job.id))).fetchall()
                requeued += [(row[0],) for row in done]
            return requeued

    def quarantine_lost_compute_jobs(self, compute_queue: str = "default", max_lost: int = 2) -> list[str]:
        """Fail (quarantine) compute jobs whose lease expired for the ``max_lost``-th time.

        A compute job's own crash is caught by its supervisor (the job runs in a child
        process); a lease that expires means the supervising worker itself died.  Once is a
        restart; twice, the job is suspected of taking its worker down, and it is failed with
        the reason instead of being claimed again.  Run before :meth:`reap`.
        """
        rows = self._run(
            update(Job)
            .where(and_(col(Job.status) == "running", col(Job.lease_until) < time.time(),
                        col(Job.queue) == compute_queue, col(Job.attempts) >= max_lost))
            .values(
                status="failed", finished_at=utcnow(), lease_until=None, revision=col(Job.revision) + 1,
                message=f"failed: quarantined after its worker was lost {max_lost} times",
                error={"type": "about:blank#quarantined", "title": "Job quarantined", "status": 500,
                       "detail": f"its worker was lost {max_lost} times while running it; the job is "
                                 "failed instead of being claimed again"})
            .returning(col(Job.id)))
        return [r[0] for r in rows]


LOST_LEASE_REASON = "its worker stopped reporting (the lease expired); the job was queued again"


def final_message(status: str, error: dict | None) -> Any:
    """The message a job keeps once it finished, never the last progress line of a run that
    did not get to its end ("probing 3/17" on a failed job reads as if it still probed).

    succeeded / needs_attention: the kind's own closing words when it reported them at progress 1 (e.g.
    "9/9 traces done"), else "done"; failed / cancelled: the status and the error's detail.
    Returns a SQL expression for :meth:`JobStore.finish`'s conditional UPDATE."""
    if status in COMPLETED_STATES:
        return case((and_(col(Job.progress) >= 1.0, col(Job.message).is_not(None), col(Job.message) != ""),
                     col(Job.message)),
                    else_=literal("done"))
    detail = (error or {}).get("detail") or (error or {}).get("title") or ""
    return literal(f"{status}: {detail}"[:500] if detail else status)


def json_result(result: Any) -> dict:
    """A job's result as plain JSON (numpy arrays and scalars converted), as it is stored."""
    return encoded_result(result)[0]


def encoded_result(result: Any) -> tuple[dict, int]:
    """(:func:`json_result` of ``result``, the size in bytes of its JSON), from one encoding
    (the size is what :meth:`JobStore.finish` records as ``result_bytes``: the JSON of the
    plain result is the same text)."""
    text = json.dumps(result or {}, default=_json_default)
    return json.loads(text), len(text.encode())


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def completed_status(result: Any) -> str:
    """The state a job whose kind returned ``result`` (stored JSON) ends in:
    ``needs_attention`` when the result says so (its ATTENTION_KEY is true), else ``succeeded``."""
    return "needs_attention" if isinstance(result, dict) and result.get(ATTENTION_KEY) is True else "succeeded"
