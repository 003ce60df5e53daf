"""The body of a long-lived compute process: limits first, then one job at a time.

A compute process is forked from a clean, single-threaded fork server (``multiprocessing``'s
"forkserver" context) that has imported the compute core once, so it starts in tens of
milliseconds and never shares the threads, locks or serial ports of the process that
supervises it (:mod:`app.runtime.compute_pool`).  It then serves jobs, one at a time, that
its supervisor sends through a pipe, and keeps what jobs built on a part (the parsed mesh
with its ray-casting structure and edge grid, fitted fields) in memory for the next job,
bounded by ``CONFORMA_COMPUTE_CACHE_MB`` (least recently used out).  Limits:

* its address space is capped (``RLIMIT_AS``): the hard limit at its size at start plus
  ``CONFORMA_JOB_MEMORY_MB`` plus ``CONFORMA_COMPUTE_RECYCLE_MB``, and before each job the
  soft limit at its size then plus ``CONFORMA_JOB_MEMORY_MB``, so each job may add exactly
  its budget to the warm process; an allocation beyond it is a ``MemoryError`` in the job
  (failed with the reason), never the kernel's OOM killer choosing a victim;
* it asks to be the OOM killer's first choice (``oom_score_adj`` 1000) should memory run
  out anyway, and to die with its fork server (``PR_SET_PDEATHSIG``) and, within 0.1 s,
  with the server that owns it (:func:`bind_to`), even when the server is SIGKILLed;
* it opens its own database engine and blob store (nothing is inherited).

Outcomes the job itself decides (succeeded, failed, cancelled) are written here, with the
same conditional transitions as a thread worker; what it cannot report (a crash, a kill, a
time limit) is the supervisor's business (:mod:`app.runtime.process_worker`).  Its large
blocks (arrays of LARGE_BLOCK_BYTES or more) are mapped on their own, so a job's freed arrays
leave at once (:func:`app.runtime.heap.map_large_blocks`); after each job the process
returns the rest of the heap memory the job freed (:func:`app.runtime.heap.trim_heap`),
then reports its memory and the parts it holds; the supervisor decides whether it is
reused or replaced.
"""

from __future__ import annotations

import ctypes
import gc
import logging
import os
import resource
import select
import signal
import threading
import time
from typing import Any

from threadpoolctl import threadpool_limits

from app.domain.errors import Cancelled, ConformaError
from app.jobs.field_runs import FIELD_FITS
from app.parts.cache import CacheStats, FieldFitStore, MeshStore, part_cache_for, record_job
from app.parts.meshes import MeshCache
from app.platform.blobs import BlobStore
from app.platform.config import Settings
from app.platform.db import make_engine
from app.platform.problems import from_error, problem
from app.runtime.context import JobContext
from app.runtime.heap import GLIBC_TRIM_BYTES, LARGE_BLOCK_BYTES, keep_heap_top, map_large_blocks, trim_heap
from app.runtime.process_identity import start_ticks
from app.runtime.registry import get_kind, load_kinds
from app.runtime.store import Claim, JobStore, completed_status, encoded_result

log = logging.getLogger("conforma.jobs.child")
_PR_SET_PDEATHSIG = 1
MIB = 2 ** 20
# a job's progress below 1 is written at most this often (s): its lease and cancel are the
# supervisor's, so progress is only what a client reads (a 50 ms job wrote two rows for it)
PROGRESS_EVERY_S = 0.25
# after a job the heap is trimmed when the process grew by this much since it last was
TRIM_GROWTH_BYTES = 32 * MIB


def _status_bytes(field: str) -> int:
    """A size field of /proc/self/status (``VmSize``, ``VmRSS``), bytes; 0 when unavailable."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _vm_size_bytes() -> int:
    """This process's current virtual size (VmSize), bytes; 0 when /proc is unavailable."""
    return _status_bytes("VmSize")


def process_limits(hard_bytes: int) -> None:
    """Cap the address space at ``hard_bytes`` (soft and hard); volunteer for the OOM
    killer; die with the parent.  Best effort where the platform lacks a mechanism."""
    resource.setrlimit(resource.RLIMIT_AS, (hard_bytes, hard_bytes))
    try:
        with open("/proc/self/oom_score_adj", "w") as adj:
            adj.write("1000")
    except OSError:
        pass
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def bind_to(server_pid: int, every_s: float = 0.1) -> None:
    """Die (SIGKILL) as soon as the server process ``server_pid`` ends.

    ``PR_SET_PDEATHSIG`` binds a process to its parent, which is the fork server here, and a
    fork server outlives its server by as long as its own shutdown takes; so a daemon thread
    watches the server itself: it sleeps on a pidfd of the server (readable when it exits; no
    CPU while it lives), or where pidfds are missing checks the server's pid and start time
    every ``every_s`` (so a reused pid is not mistaken for it).  A server already gone when
    the process binds (it died while this process was being started) ends the process at
    once.  Without /proc it does nothing.  Bind before capping the address space
    (:func:`process_limits`): a thread whose start-up meets the cap dies before it reports
    started, and ``Thread.start`` waits for that report forever."""
    started = start_ticks(server_pid)
    if started is None:
        if os.path.exists("/proc/self/stat"):  # /proc is there: the server is not
            os.kill(os.getpid(), signal.SIGKILL)
        return

    def watch() -> None:
        try:
            pidfd: int | None = os.pidfd_open(server_pid)
        except (AttributeError, OSError):
            pidfd = None
        if pidfd is not None:
            if start_ticks(server_pid) == started:  # the pidfd is the server's, not a reused pid's
                select.select([pidfd], [], [])  # returns when the server exits
        else:
            while start_ticks(server_pid) == started:
                time.sleep(every_s)
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="conforma-lifeline", daemon=True).start()


def job_limit(memory_bytes: int) -> int:
    """Set the soft address-space limit at the current size + ``memory_bytes`` (never above
    the hard limit); returns the soft limit set."""
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    soft = _vm_size_bytes() + memory_bytes
    if hard != resource.RLIM_INFINITY:
        soft = min(soft, hard)
    resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    return soft


def lift_job_limit() -> None:
    """Between jobs: the soft limit back at the hard one (the process's own bookkeeping)."""
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (hard, hard))


class ChildRuntime:
    """What :class:`JobContext` needs from a runtime, opened fresh in the child and kept
    for every job the process serves."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.engine = make_engine(settings)
        self.blobs = BlobStore(settings.blob_dir)
        # the per-part cache on disk: what an earlier job's process built on a part (parsed
        # mesh, face normals, edge grid) or fitted to a probe run is loaded, not rebuilt
        self.part_cache = part_cache_for(settings)
        # ...and in memory, for the next job of this process: the mesh objects themselves,
        # with what is built on them (embree's ray structure cannot be stored on disk)
        self.meshes = MeshCache(self.blobs, max_bytes=int(settings.compute_cache_mb * MIB),
                                store=MeshStore(self.part_cache) if self.part_cache else None)
        FIELD_FITS.backing = FieldFitStore(self.part_cache) if self.part_cache else None
        self.store = JobStore(self.engine, settings.lease_s)
        self.served = 0
        self.progress_every_s = PROGRESS_EVERY_S
        self.trimmed_rss = _status_bytes("VmRSS")  # resident bytes when the heap was last trimmed

    def begin_job(self) -> dict[str, Any]:
        """Before each job: per-job cache counters; returns what the process held then."""
        self.served += 1
        if self.part_cache is not None:
            self.part_cache.stats = CacheStats()
        self.meshes.counts = dict.fromkeys(self.meshes.counts, 0)
        return {"process_job": self.served, "held": sorted(self.meshes.parts())}

    def persist_caches(self, claim: Claim, start: dict[str, Any]) -> None:
        """Store what this job built for the next process; journal the cache's use.  Never
        fails the job (a full disk only costs the next job the rebuild)."""
        if self.part_cache is None:
            return
        try:
            self.meshes.persist()
        except Exception:
            log.exception("part cache: persisting after job %s failed", claim.job_id)
        record_job(self.part_cache, claim.job_id, claim.kind,
                   memory={**self.meshes.counts, **start})

    def report(self) -> dict[str, Any]:
        """After a job: memory and the parts held (the supervisor's reuse and affinity).  When
        the cache let a part go, or the process grew by TRIM_GROWTH_BYTES since it last
        trimmed, the cycle collector runs (trimesh objects hold cycles: an evicted mesh is freed
        now) and the freed heap goes back to the system; after a small job neither (a full
        collection and ``malloc_trim`` cost more than a 20 mm cube's slice)."""
        held = self.meshes.parts()
        cache_bytes = self.meshes.bytes  # re-measured: evicts down to the bound
        parts = self.meshes.parts()
        rss = _status_bytes("VmRSS")
        if len(parts) < len(held) or rss > self.trimmed_rss + TRIM_GROWTH_BYTES:
            gc.collect()
            trim_heap()  # what the job freed goes back to the system, not kept at the job's peak
            rss = self.trimmed_rss = _status_bytes("VmRSS")
        return {"served": self.served, "rss_bytes": rss, "vm_bytes": _vm_size_bytes(),
                "cache_bytes": cache_bytes, "held": sorted(parts)}

    def submit(self, kind_name: str, params: dict[str, Any], *, parent_id: str | None = None) -> Any:
        raise ConformaError("compute jobs cannot submit child jobs (use a workflow kind)",
                            field="kind", value=kind_name)


def memory_problem(memory_mb: float) -> dict:
    return problem(422, "Job exceeded its memory limit",
                   f"the job needed more than its memory limit of {memory_mb:g} MiB "
                   "(CONFORMA_JOB_MEMORY_MB); reduce its parameters")


def run_job(runtime: ChildRuntime, claim: Claim) -> bool:
    """Run ``claim``'s job to an outcome in this process; True when the process is fit for
    another job (False after a MemoryError or a crash: its state may be half built)."""
    settings = runtime.settings
    start = runtime.begin_job()
    kind = get_kind(claim.kind)
    if kind is None:
        runtime.store.finish(claim, "failed", error=problem(422, "Unknown job kind", f"no worker kind {claim.kind!r}"))
        return True
    ctx = JobContext(runtime, claim)  # type: ignore[arg-type]
    keep_heap_top(kind.heap_keep_bytes or GLIBC_TRIM_BYTES)  # the kind's own, else glibc's
    job_limit(int(settings.job_memory_mb * MIB))
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        result = kind.run(ctx, kind.params.model_validate(claim.params))
        encoded, size = encoded_result(result)
        lift_job_limit()
        start.update(wall_s=round(time.perf_counter() - wall, 4), cpu_s=round(time.process_time() - cpu, 4))
        runtime.persist_caches(claim, start)  # before the outcome: the next job may start at once
        runtime.store.finish(claim, completed_status(encoded), result=encoded, result_bytes=size)
    except Cancelled as exc:
        lift_job_limit()
        runtime.store.finish(claim, "cancelled", error=from_error(exc))
    except ConformaError as exc:
        lift_job_limit()
        runtime.store.finish(claim, "failed", error=from_error(exc))
    except MemoryError:
        lift_job_limit()
        runtime.store.finish_surely(claim, "failed", error=memory_problem(settings.job_memory_mb))
        return False
    except Exception as exc:  # a bug: record it without a stack trace for clients
        lift_job_limit()
        log.exception("job %s (%s) crashed", claim.job_id, claim.kind)
        runtime.store.finish(claim, "failed", error=problem(500, "Job crashed", f"{type(exc).__name__}: {exc}"[:500]))
        return False
    return True


def freeze_startup_objects() -> None:
    """Put everything the process holds so far (the imported modules, the runtime: ~230k
    objects that live as long as the process) out of the cycle collector's sight
    (:func:`gc.freeze`): the full collection after each job (:meth:`ChildRuntime.report`)
    then scans only what jobs made (measured: ~0.1 s per job before, ~0 after)."""
    gc.freeze()


def serve_jobs(settings: Settings, conn: Any, server_pid: int | None = None) -> None:
    """Entry point of a compute process: limits, bound to the life of ``server_pid`` (the
    process that owns the pool: :func:`bind_to`), then jobs from ``conn`` (a pipe end) until
    it sends None or closes.  After each job it sends its report (:meth:`ChildRuntime.report`
    plus ``fit``: False when it should not serve another job)."""
    if server_pid is not None:
        bind_to(server_pid)  # before the cap (see bind_to)
    process_limits(_vm_size_bytes() + int((settings.job_memory_mb + settings.compute_recycle_mb) * MIB))
    threadpool_limits(limits=settings.blas_threads)  # once per process, never inside the core
    map_large_blocks(LARGE_BLOCK_BYTES)  # a job's large arrays go back to the system when freed
    load_kinds(settings.job_plugins.split(","))
    runtime = ChildRuntime(settings)
    freeze_startup_objects()
    try:
        while True:
            try:
                claim = conn.recv()
            except (EOFError, OSError):
                return
            if claim is None:
                return
            fit = run_job(runtime, claim)
            conn.send({**runtime.report(), "job_id": claim.job_id, "fit": fit,
                       "hard_bytes": resource.getrlimit(resource.RLIMIT_AS)[1]})
    finally:
        runtime.engine.dispose()
