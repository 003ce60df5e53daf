"""A small pool of long-lived compute processes, one job at a time each, reused.

Forking a fresh process per job (the single-job form, ``CONFORMA_COMPUTE_RECYCLE_JOBS=1``)
throws away whatever the job built on its part: the parsed mesh, embree's ray-casting
structure (seconds on a 1M-face part, and embree cannot store it), the edge grid, fitted
fields.  So a :class:`ComputePool` keeps up to ``size`` processes
(:func:`app.runtime.compute_child.serve_jobs`) alive between jobs; each holds a bounded
in-memory cache of what its jobs built.

* **Affinity, never waiting.**  :meth:`ComputePool.acquire` gives an idle process that
  already holds one of the job's parts (by mesh sha256) when there is one, else the idle
  process used least recently, else a new process: a job never waits for a busy process.
* **Isolation kept.**  Every process has its own address-space limit, and the supervisor
  (:mod:`app.runtime.process_worker`) keeps each job's wall-clock limit, its SIGKILL on
  cancel and its quarantine on a crash; a process that was killed or died is
  :meth:`discarded <ComputePool.discard>` and a fresh one takes its place.
* **Small while idle.**  The pool keeps ``CONFORMA_COMPUTE_IDLE_PROCESSES`` processes (1)
  while no job needs more (the warm-up starts that many); a process started because jobs ran
  at once ends once it has been idle EXTRA_IDLE_S, so a service whose jobs run one after
  another (a board's closed loop) holds one compute process's memory, not ``size``.
* **Recycled.**  After a job that leaves its process above ``CONFORMA_COMPUTE_RECYCLE_MB``
  resident (or its address space grown by more), after ``CONFORMA_COMPUTE_RECYCLE_JOBS``
  jobs, or after a job that ran out of memory or crashed in Python, the process is ended and
  replaced (:func:`retire_reason`).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from app.platform.config import Settings
from app.runtime.compute_child import serve_jobs

log = logging.getLogger("conforma.jobs.pool")
MIB = 2 ** 20
STOP_WAIT_S = 2.0
EXTRA_IDLE_S = 30.0  # a process beyond the ones kept idle ends after this long without a job
# Imported once by the fork server, so that every child starts with the compute core loaded
# (and the circuit importers with their ECAD libraries: an import's child reads at once).
PRELOAD = ["app.runtime.compute_child", "app.jobs.circuit_import", "app.circuits.dxf", "app.circuits.svg",
           "app.circuits.gerber", "app.circuits.kicad"]
_context_lock = threading.Lock()
_context: multiprocessing.context.ForkServerContext | None = None


def mp_context() -> multiprocessing.context.ForkServerContext:
    """The forkserver context (started once per process, preloading the compute core)."""
    global _context
    with _context_lock:
        if _context is None:
            from app.runtime.registry import kind_modules

            context = multiprocessing.get_context("forkserver")
            assert isinstance(context, multiprocessing.context.ForkServerContext)
            context.set_forkserver_preload(PRELOAD + kind_modules())
            _context = context
        return _context


@dataclass(eq=False)
class Member:
    """One compute process of the pool and what the supervisor knows about it."""

    process: Any
    conn: Any
    held: frozenset[str] = frozenset()  # parts (mesh sha256) it held after its last job
    served: int = 0
    busy: bool = False
    last_used: float = field(default_factory=time.monotonic)

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def alive(self) -> bool:
        return self.process.exitcode is None

    def kill(self, wait_s: float = 5.0) -> int | None:
        """SIGKILL and reap; returns the exit code (None if it could not be reaped in time)."""
        if self.process.exitcode is None:
            self.process.kill()
        self.process.join(wait_s)
        return self._close()

    def stop(self) -> None:
        """Ask it to exit after its (finished) job; SIGKILL when it does not within a moment."""
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.process.join(STOP_WAIT_S)
        self.kill()

    def _close(self) -> int | None:
        code = self.process.exitcode
        try:
            self.conn.close()
        except OSError:
            pass
        if code is not None:
            self.process.close()
        return code


def retire_reason(settings: Settings, member: Member, report: dict[str, Any]) -> str | None:
    """Why ``member`` must not serve another job after ``report`` (its answer to a job), or None."""
    if not report.get("fit", True):
        return "its job ran out of memory or crashed"
    if report.get("served", 0) >= settings.compute_recycle_jobs:
        return f"it served {report.get('served')} jobs (CONFORMA_COMPUTE_RECYCLE_JOBS)"
    limit = settings.compute_recycle_mb * MIB
    if report.get("rss_bytes", 0) > limit:
        return f"its resident memory is {report['rss_bytes'] / MIB:.0f} MiB (CONFORMA_COMPUTE_RECYCLE_MB)"
    hard = report.get("hard_bytes")
    if isinstance(hard, int) and hard > 0 and report.get("vm_bytes", 0) + settings.job_memory_mb * MIB > hard:
        return "its address space grew too far for another job's full memory budget"
    return None


class ComputePool:
    """Up to ``settings.worker_threads`` long-lived compute processes (see the module)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.size = settings.worker_threads
        self.keep = min(settings.compute_idle_processes, self.size)  # processes kept while idle
        self._members: list[Member] = []
        self._shrinker: threading.Timer | None = None
        self._lock = threading.Condition()
        self._starting = 0  # processes being started by replenish()
        self._waiting = 0  # jobs waiting for one of them
        self.closed = False
        self.started = 0  # processes started (tests and benchmarks read it)

    @property
    def members(self) -> list[Member]:
        with self._lock:
            return list(self._members)

    def _spawn(self) -> Member:
        context = mp_context()
        parent, child = context.Pipe()
        process = context.Process(target=serve_jobs, args=(self.settings, child, os.getpid()), name="conforma-compute",
                                  daemon=True)
        process.start()  # the first start waits for the fork server to import the compute core
        child.close()
        self.started += 1
        return Member(process, parent)

    def acquire(self, parts: set[str]) -> Member:
        """A process for a job on ``parts`` (mesh sha256s), marked busy: an idle one holding
        one of them, else the idle one used least recently, else one being started that no
        other job waits for, else a new one.  A job never waits for a busy process."""
        dead: list[Member] = []
        chosen: Member | None = None
        with self._lock:
            while True:
                if self.closed:
                    raise RuntimeError("the compute pool is closed")
                for member in [m for m in self._members if not m.busy and not m.alive()]:
                    self._members.remove(member)
                    dead.append(member)
                idle = [m for m in self._members if not m.busy]
                if idle:
                    chosen = max(idle, key=lambda m: (len(m.held & parts), -m.last_used))
                    chosen.busy = True
                    break
                if self._starting <= self._waiting:
                    break
                self._waiting += 1  # a process is being started (the warm-up, a replacement): take it
                try:
                    self._lock.wait(1.0)
                finally:
                    self._waiting -= 1
        for member in dead:
            log.warning("compute process %s ended while idle (exit %s); replaced", member.pid, member._close())
        if chosen is not None:
            return chosen
        member = self._spawn()
        member.busy = True
        with self._lock:
            self._members.append(member)
            closed = self.closed
        if closed:
            self.discard(member)
            raise RuntimeError("the compute pool is closed")
        return member

    def release(self, member: Member, report: dict[str, Any]) -> str | None:
        """``member`` answered its job with ``report``: back to idle, or retired (and replaced)
        when :func:`retire_reason` says so; returns the reason."""
        member.served = int(report.get("served", member.served + 1))
        member.held = frozenset(report.get("held", ()))
        member.last_used = time.monotonic()
        reason = retire_reason(self.settings, member, report)
        extra: Member | None = None
        with self._lock:
            if reason is None and self.closed:
                reason = "the pool is closed"
            if reason is None:
                member.busy = False
                if len(self._members) > self.size:  # one too many: the idle one worth least goes
                    idle = [m for m in self._members if not m.busy]
                    extra = min(idle, key=lambda m: (bool(m.held), m.last_used))
                    self._members.remove(extra)
            elif member in self._members:
                self._members.remove(member)
        if extra is not None:
            log.info("compute process %s retired: the pool has more processes than its size", extra.pid)
            extra.stop()
        if reason is None:
            self._shrink_later()
            return None
        log.info("compute process %s retired: %s", member.pid, reason)
        member.stop()
        self.replenish()
        return reason

    def give_back(self, member: Member) -> None:
        """``member`` was acquired for a job that was cancelled before it was sent: idle again,
        unused (ended instead when the pool has closed meanwhile)."""
        with self._lock:
            closed = self.closed
            if not closed:
                member.busy = False
                self._lock.notify_all()
            elif member in self._members:
                self._members.remove(member)
        if closed:
            member.stop()
        else:
            self._shrink_later()

    def _shrink_later(self, delay_s: float | None = None) -> None:
        """Have :meth:`shrink` run once in ``delay_s`` (default EXTRA_IDLE_S) when the pool
        holds more processes than it keeps idle and no such run is pending."""
        with self._lock:
            if self.closed or len(self._members) <= self.keep:
                return
            if self._shrinker is not None and self._shrinker.is_alive():
                return
            self._shrinker = threading.Timer(EXTRA_IDLE_S if delay_s is None else delay_s, self.shrink)
            self._shrinker.daemon = True
            self._shrinker.name = "compute-pool-shrink"
            self._shrinker.start()

    def shrink(self) -> list[int | None]:
        """End the idle processes beyond the ones kept idle (``keep``) that have been idle
        EXTRA_IDLE_S or longer, those holding no part and used least recently first; run
        again later while others are still beyond it.  Returns the pids ended."""
        ended: list[Member] = []
        now = time.monotonic()
        with self._lock:
            while len(self._members) > self.keep:
                idle = [m for m in self._members if not m.busy and now - m.last_used >= EXTRA_IDLE_S]
                if not idle:
                    break
                member = min(idle, key=lambda m: (bool(m.held), m.last_used))
                self._members.remove(member)
                ended.append(member)
            waiting = [m for m in self._members if not m.busy] if len(self._members) > self.keep else []
            self._shrinker = None
        pids = [m.pid for m in ended]  # read before stop(): a stopped member's process is closed
        for member in ended:
            log.info("compute process %s ended: idle %.0f s beyond the %d kept", member.pid, now - member.last_used,
                     self.keep)
            member.stop()
        if waiting:  # extras that are idle, not for long enough yet
            self._shrink_later(max(0.1, EXTRA_IDLE_S - (now - max(m.last_used for m in waiting))))
        return pids

    def discard(self, member: Member, wait_s: float = 5.0) -> int | None:
        """Forget ``member`` (killed, crashed, or unusable): SIGKILL it if it still runs;
        returns its exit code.  Call :meth:`replenish` after recording its job's outcome."""
        with self._lock:
            if member in self._members:
                self._members.remove(member)
        return member.kill(wait_s)

    def replenish(self) -> None:
        """Start processes until the pool holds the ``keep`` it keeps idle (a fresh one takes a
        lost one's place; more are started by :meth:`acquire` when jobs run at once)."""
        while True:
            with self._lock:
                if self.closed or len(self._members) + self._starting >= self.keep:
                    return
                self._starting += 1
            member = None
            try:
                member = self._spawn()
            except Exception:
                log.exception("could not start a compute process")
            with self._lock:
                self._starting -= 1
                closed = self.closed
                if member is not None and not closed:
                    self._members.append(member)
                self._lock.notify_all()
            if member is None:
                return
            if closed:
                member.kill()
                return

    def close(self) -> None:
        """End the idle processes (busy ones are ended by their supervisors, then released)."""
        with self._lock:
            self.closed = True
            if self._shrinker is not None:
                self._shrinker.cancel()
            idle = [m for m in self._members if not m.busy]
            for member in idle:
                self._members.remove(member)
            self._lock.notify_all()
        for member in idle:
            member.stop()
