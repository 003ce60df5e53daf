"""Compute jobs in processes of their own: supervised, limited, killed hard, quarantined.

The process that owns the serial ports (``conforma serve``) must survive whatever a
compute job does.  So a worker thread of the ``default`` queue (in ``serve`` or in a
``conforma worker``) claims the job and then only *supervises* it: the job runs in a
long-lived compute process of the runtime's :class:`~app.runtime.compute_pool.ComputePool`
(one job at a time, reused for later jobs so that what a job built on its part stays warm;
it prefers a process that already holds the job's part), while the thread

* renews the job's lease and polls its cancel flag every ``POLL_S`` (0.1 s): a cancel is
  a ``SIGKILL`` of the job's process, recorded as ``cancelled`` well within 1 s, whatever
  loop the job is in; a fresh process takes the killed one's place.  It polls while the job
  still waits for its process too (a process being started takes seconds): the job is then
  cancelled at once and never sent to the process found for it;
* kills the process after ``CONFORMA_JOB_TIME_S`` wall-clock seconds of the job (failed,
  with the limit);
* when the process dies without reporting the job's end (a signal: the OOM killer, a
  segfault, an abort in native code), **quarantines** the job: failed with the reason, never
  re-claimed; the process is replaced;
* when its own runtime stops, kills the process and puts the job back in the queue
  (``released``), so that a normal restart runs it again;
* records the process that runs each attempt (``jobs.process``: pid, start time, boot) and,
  before a later attempt runs (its server was SIGKILLed and restarted, its lease expired),
  makes sure that process has ended: it waits ``EARLIER_WAIT_S`` for it (a compute process
  dies within 0.1 s of its server), then SIGKILLs it; one that survives even that puts the
  job back in the queue (``released``).  Two attempts of a job never compute at once.

Machine and workflow jobs stay in threads of the ``serve`` process (they need its ports).
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from sqlalchemy import select
from sqlmodel import col

from app.domain.errors import Cancelled
from app.platform.models import TERMINAL_STATES, Job, JobReference, Part, Trace
from app.platform.problems import from_error, problem
from app.runtime import process_identity
from app.runtime.compute_pool import ComputePool, Member, mp_context
from app.runtime.store import Claim, JobStore

if TYPE_CHECKING:
    from app.runtime.engine import Runtime

log = logging.getLogger("conforma.jobs.process")
POLL_S = 0.1
KILL_WAIT_S = 5.0
EARLIER_WAIT_S = 1.0  # how long an earlier attempt's process may take to end by itself


def _signal_name(exitcode: int) -> str:
    try:
        return signal.Signals(-exitcode).name
    except ValueError:
        return f"signal {-exitcode}"


def quarantine_problem(exitcode: int) -> dict:
    """The error recorded for a job whose process died without reporting an outcome."""
    how = (f"was killed by {_signal_name(exitcode)}" if exitcode < 0 else f"exited with status {exitcode}")
    hint = " (the kernel's OOM killer sends SIGKILL: the job likely ran out of memory)" if exitcode == -9 else ""
    return problem(500, "Job process crashed",
                   f"the job's process {how}{hint}; the job is quarantined (failed, not retried) so that it "
                   "cannot take a worker down again")


def time_limit_problem(limit_s: float) -> dict:
    return problem(422, "Job exceeded its time limit",
                   f"the job ran longer than its limit of {limit_s:g} s (CONFORMA_JOB_TIME_S) and was killed; "
                   "reduce its parameters")


@contextmanager
def _lease_kept(store: JobStore, claim: Claim, every_s: float) -> Iterator[None]:
    """Renew ``claim``'s lease from a thread while the body blocks."""
    done = threading.Event()

    def renew() -> None:
        while not done.wait(every_s):
            try:
                store.heartbeat(claim)
            except Exception:  # a locked database: the next renewal tries again
                log.warning("could not renew the lease of job %s", claim.job_id, exc_info=True)

    thread = threading.Thread(target=renew, daemon=True, name=f"lease-{claim.job_id}")
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


@dataclass(eq=False)
class _Handoff:
    """What the thread that finds a job's process and the thread that supervises the job
    share: the job is sent only under ``lock`` and only while not ``abandoned``."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    done: threading.Event = field(default_factory=threading.Event)
    abandoned: bool = False
    sent: bool = False
    member: Member | None = None
    error: BaseException | None = None


def warm_up(pool: ComputePool | None = None) -> None:
    """Start the fork server now (it imports the compute core: seconds), not at the first
    job; with ``pool``, start its processes too."""
    if pool is not None:
        pool.replenish()
    else:
        mp_context().Process(target=_noop).start()


def _noop() -> None:
    return None


class ProcessSupervisor:
    """Runs claimed compute jobs in the processes of a :class:`ComputePool`, one :class:`Runtime`'s."""

    def __init__(self, runtime: Runtime) -> None:
        self.runtime = runtime
        self.settings = runtime.settings
        self.pool = ComputePool(runtime.settings)
        self.stopping = threading.Event()
        self._idle = threading.Condition()
        self._active = 0

    def _cancel_requested(self, job_id: str) -> bool:
        with self.runtime.engine.connect() as conn:
            return bool(conn.execute(select(col(Job.cancel_requested)).where(col(Job.id) == job_id)).scalar())

    def parts_of(self, job_id: str) -> set[str]:
        """The mesh sha256 of every part the job reads (directly, or through its traces)."""
        with self.runtime.engine.connect() as conn:
            refs = conn.execute(select(col(JobReference.ref_kind), col(JobReference.ref_id))
                                .where(col(JobReference.job_id) == job_id)).all()
            part_ids = {ref_id for kind, ref_id in refs if kind == "part"}
            trace_ids = [ref_id for kind, ref_id in refs if kind == "trace"]
            if trace_ids:
                part_ids |= set(conn.execute(select(col(Trace.part_id)).where(col(Trace.id).in_(trace_ids))).scalars())
            if not part_ids:
                return set()
            return set(conn.execute(select(col(Part.sha256)).where(col(Part.id).in_(part_ids))).scalars())

    def run(self, claim: Claim) -> None:
        """Run ``claim``'s job in a compute process and see it to an outcome (blocks)."""
        with self._idle:
            self._active += 1
        try:
            self._supervise(claim)
        finally:
            with self._idle:
                self._active -= 1
                self._idle.notify_all()

    def _start(self, claim: Claim, handoff: _Handoff) -> Member | None:
        """A pool process that has received ``claim`` (a process that died idle is replaced),
        or None when the supervisor gave the job up while the process was being found."""
        try:
            parts = self.parts_of(claim.job_id)
        except Exception:  # affinity is an optimisation: never a reason to fail the job
            log.exception("could not read the parts of job %s", claim.job_id)
            parts = set()
        for attempt in range(3):
            member = self.pool.acquire(parts)
            with handoff.lock:
                if handoff.abandoned:  # cancelled or stopping meanwhile: the job never reaches it
                    self.pool.give_back(member)
                    return None
                try:  # recorded before the job starts: a server killed after the send leaves its trace
                    self.runtime.store.record_process(claim, process_identity.identify(member.pid))
                except Exception:
                    log.exception("could not record the process of job %s", claim.job_id)
                try:
                    member.conn.send(claim)
                    handoff.sent = True
                    return member
                except (OSError, ValueError):  # it died while idle: another one
                    self.pool.discard(member)
                    if attempt == 2:
                        raise
        raise AssertionError("unreachable")

    def _start_watched(self, claim: Claim) -> Member | str:
        """:meth:`_start` in a thread of its own while this one keeps polling the cancel flag
        and the stop: a job waits for a process for seconds when the pool starts one (the
        first start imports the compute core), and a cancel in that time takes effect at once.
        Returns the member that received the job, or the verdict (``cancel``, ``stop``) that
        ended the wait; raises what :meth:`_start` raised."""
        handoff = _Handoff()

        def start() -> None:
            try:
                handoff.member = self._start(claim, handoff)
            except BaseException as exc:  # handed over to the supervising thread
                handoff.error = exc
            finally:
                handoff.done.set()

        threading.Thread(target=start, name=f"conforma-start-{claim.job_id[:8]}", daemon=True).start()
        while not handoff.done.wait(POLL_S):
            try:
                verdict = "stop" if self.stopping.is_set() else (
                    "cancel" if self._cancel_requested(claim.job_id) else None)
            except Exception:  # a database hiccup: ask again at the next poll
                log.exception("waiting for a process for job %s", claim.job_id)
                continue
            if verdict is not None:
                with handoff.lock:
                    if not handoff.sent:
                        handoff.abandoned = True
                        return verdict
                break  # the job reached its process just now: supervise it
        handoff.done.wait()
        if handoff.error is not None:
            raise handoff.error
        if handoff.member is None:  # abandoned only by this thread, which returned above
            raise AssertionError("a process start ended without a process")
        return handoff.member

    def _earlier_process_gone(self, claim: Claim) -> bool:
        """Whether the process of ``claim``'s earlier attempt has ended (waited for, or
        killed); False when it survives."""
        if claim.earlier_process is None:
            return True
        how = process_identity.make_gone(claim.earlier_process, EARLIER_WAIT_S, KILL_WAIT_S)
        if how in ("exited", "killed"):
            log.warning("job %s: the process %s of its earlier attempt still ran; it %s before attempt %d",
                        claim.job_id, claim.earlier_process.get("pid"), "ended" if how == "exited" else "was killed",
                        claim.attempt)
        return how != "alive"

    def _supervise(self, claim: Claim) -> None:
        store = self.runtime.store
        with _lease_kept(store, claim, self.settings.lease_s / 3):
            gone = self._earlier_process_gone(claim)
        if not gone:
            log.error("job %s: the process %s of its earlier attempt survives SIGKILL; the job waits in the queue",
                      claim.job_id, claim.earlier_process and claim.earlier_process.get("pid"))
            store.release(claim, "waiting for the process of its earlier attempt to end")
            return
        try:
            with _lease_kept(store, claim, self.settings.lease_s / 3):
                started_or_verdict = self._start_watched(claim)
        except Exception as exc:  # no process, no job: say so rather than leave it running
            if self.stopping.is_set():  # the pool closed while the job waited for a process
                store.release(claim, "released by a stopping worker")
                return
            log.exception("could not start a process for job %s", claim.job_id)
            store.finish(claim, "failed",
                         error=problem(500, "Job could not start", f"{type(exc).__name__}: {exc}"[:500]))
            return
        if isinstance(started_or_verdict, str):  # cancelled or stopped before it reached a process
            self._record(claim, started_or_verdict, None, before_start=True)
            return
        member = started_or_verdict
        started = time.monotonic()
        renew_every = self.settings.lease_s / 3
        renewed = started
        verdict: str | None = None  # why the supervisor ended it: cancel, time, lost, stop
        report: dict[str, Any] | None = None
        while verdict is None:
            if member.conn.poll(POLL_S):  # the job's end, or EOF: the process died
                report = self._receive(member)
                break
            try:
                verdict = self._verdict(claim, started, renewed)
            except Exception:  # a database hiccup must not leave the process unwatched: ask again
                log.exception("supervising job %s", claim.job_id)
                continue
            if verdict is None and time.monotonic() - renewed >= renew_every:
                renewed = time.monotonic()
        if (report is None and verdict in ("cancel", "time", "lost") and self._recorded(claim)
                and member.conn.poll(KILL_WAIT_S)):
            report = self._receive(member)  # the job recorded its own end first: let it report
        if report is not None:
            self.pool.release(member, report)
            return
        exitcode = self.pool.discard(member, KILL_WAIT_S)
        with _lease_kept(store, claim, renew_every):  # the outcome's write may wait for the database
            self._record(claim, verdict, exitcode)
        self.pool.replenish()  # after the outcome: a cancel is recorded first

    @staticmethod
    def _receive(member: Member) -> dict[str, Any] | None:
        """The process's report, or None when it died (EOF)."""
        try:
            report = member.conn.recv()
        except (EOFError, OSError):
            return None
        return report if isinstance(report, dict) else None

    def _recorded(self, claim: Claim) -> bool:
        """Whether the job has an outcome already (written by its process just now)."""
        try:
            status = self.runtime.store.status(claim.job_id)
        except Exception:
            return False
        return status is not None and status[0] in TERMINAL_STATES

    def _verdict(self, claim: Claim, started: float, renewed: float) -> str | None:
        """Why the running job's process must end now (stop, time, cancel, lost), or None;
        renews the lease when it is due."""
        now = time.monotonic()
        if self.stopping.is_set():
            return "stop"
        if now - started > self.settings.job_time_s:
            return "time"
        if self._cancel_requested(claim.job_id):
            return "cancel"
        if now - renewed >= self.settings.lease_s / 3 and self.runtime.store.heartbeat(claim) is None:
            return "lost"
        return None

    def _record(self, claim: Claim, verdict: str | None, exitcode: int | None, before_start: bool = False) -> None:
        """The outcome the process could not record itself (each transition is conditional on
        ``claim`` still owning a running job, so a result the process wrote first stands);
        ``before_start``: the job never reached a process."""
        store = self.runtime.store
        if verdict == "cancel":
            how = "before it reached a compute process" if before_start else "(its process was killed)"
            cancelled = Cancelled(f"the job was cancelled {how}", field="job_id", value=claim.job_id)
            store.finish_surely(claim, "cancelled", error=from_error(cancelled))
        elif verdict == "time":
            store.finish_surely(claim, "failed", error=time_limit_problem(self.settings.job_time_s))
        elif verdict == "stop":
            store.release(claim, "released by a stopping worker")
        elif verdict is None and exitcode not in (0, None):
            if store.finish_surely(claim, "failed", error=quarantine_problem(exitcode)):
                log.warning("job %s (%s) quarantined: its process ended with %s", claim.job_id, claim.kind, exitcode)
        elif verdict is None:  # exited without an outcome: a bug, not a retry
            store.finish_surely(claim, "failed",
                                error=problem(500, "Job crashed", "the job's process ended without a result"))

    def stop(self, timeout_s: float = 3.0) -> None:
        """Kill running jobs' processes and wait (up to ``timeout_s``) until their jobs are
        released; end the idle processes."""
        self.stopping.set()
        self.pool.close()
        with self._idle:
            self._idle.wait_for(lambda: self._active == 0, timeout_s)
        self.pool.close()  # the processes of jobs released meanwhile
