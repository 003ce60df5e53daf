"""The body of a compute job's own process: limits first, then the job.

A child is forked from a clean, single-threaded fork server (``multiprocessing``'s
"forkserver" context) that has imported the compute core once, so a job starts in tens of
milliseconds and never shares the threads, locks or serial ports of the process that
supervises it.  Before the job runs, the child

* caps its address space (``RLIMIT_AS``) at its size at start plus
  ``CONFORMA_JOB_MEMORY_MB``, so an allocation beyond the budget is a ``MemoryError`` in
  the job (failed with the reason), never the kernel's OOM killer choosing a victim;
* asks to be the OOM killer's first choice (``oom_score_adj`` 1000) should memory run out
  anyway, and to die with its fork server (``PR_SET_PDEATHSIG``) when the service dies;
* opens its own database engine and blob store (nothing is inherited).

Outcomes the job itself decides (succeeded, failed, cancelled) are written here, with the
same conditional transitions as a thread worker; what it cannot report (a crash, a kill)
is the supervisor's business (:mod:`app.jobs.process_worker`).
"""

from __future__ import annotations

import ctypes
import logging
import resource
import signal
from typing import Any

from app.blobs import BlobStore
from app.config import Settings
from app.db import make_engine
from app.errors import Cancelled, ConformaError
from app.jobs.context import JobContext
from app.jobs.registry import get_kind, load_kinds
from app.jobs.store import Claim, JobStore, json_result
from threadpoolctl import threadpool_limits

from app.part_cache import FieldFitStore, MeshStore, part_cache_for, record_job
from app.problems import from_error, problem
from app.records import FIELD_FITS, MeshCache

log = logging.getLogger("conforma.jobs.child")
_PR_SET_PDEATHSIG = 1


def _vm_size_bytes() -> int:
    """This process's current virtual size (VmSize), bytes; 0 when /proc is unavailable."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def apply_limits(memory_bytes: int) -> None:
    """Cap the address space at the current size + ``memory_bytes``; volunteer for the OOM
    killer; die with the parent.  Best effort where the platform lacks a mechanism."""
    limit = _vm_size_bytes() + memory_bytes
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    try:
        with open("/proc/self/oom_score_adj", "w") as adj:
            adj.write("1000")
    except OSError:
        pass
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass


class ChildRuntime:
    """What :class:`JobContext` needs from a runtime, opened fresh in the child."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.engine = make_engine(settings)
        self.blobs = BlobStore(settings.blob_dir)
        # the per-part cache on disk: what an earlier job's process built on a part (parsed
        # mesh, face normals, edge grid) or fitted to a probe run is loaded, not rebuilt
        self.part_cache = part_cache_for(settings)
        self.meshes = MeshCache(self.blobs, store=MeshStore(self.part_cache) if self.part_cache else None)
        FIELD_FITS.backing = FieldFitStore(self.part_cache) if self.part_cache else None
        self.store = JobStore(self.engine, settings.lease_s)

    def persist_caches(self, claim: Claim) -> None:
        """Store what this job built for the next process; journal the cache's use.  Never
        fails the job (a full disk only costs the next job the rebuild)."""
        if self.part_cache is None:
            return
        try:
            self.meshes.persist()
        except Exception:
            log.exception("part cache: persisting after job %s failed", claim.job_id)
        record_job(self.part_cache, claim.job_id, claim.kind)

    def submit(self, kind_name: str, params: dict[str, Any], *, parent_id: str | None = None) -> Any:
        raise ConformaError("compute jobs cannot submit child jobs (use a workflow kind)",
                            field="kind", value=kind_name)



def memory_problem(memory_mb: float) -> dict:
    return problem(422, "Job exceeded its memory limit",
                   f"the job needed more than its memory limit of {memory_mb:g} MiB "
                   "(CONFORMA_JOB_MEMORY_MB); reduce its parameters")


def run_child(settings: Settings, claim: Claim) -> None:
    """Entry point of the child process: limits, then run ``claim``'s job to an outcome."""
    apply_limits(int(settings.job_memory_mb * 2**20))
    threadpool_limits(limits=settings.blas_threads)  # once per job process, never inside the core
    load_kinds(settings.job_plugins.split(","))
    runtime = ChildRuntime(settings)
    kind = get_kind(claim.kind)
    try:
        if kind is None:
            runtime.store.finish(claim, "failed", error=problem(422, "Unknown job kind",
                                                                f"no worker kind {claim.kind!r}"))
            return
        ctx = JobContext(runtime, claim)  # type: ignore[arg-type]
        try:
            result = kind.run(ctx, kind.params.model_validate(claim.params))
            encoded = json_result(result)
            runtime.persist_caches(claim)  # before the outcome: the next job may start at once
            runtime.store.finish(claim, "succeeded", result=encoded)
        except Cancelled as exc:
            runtime.store.finish(claim, "cancelled", error=from_error(exc))
        except ConformaError as exc:
            runtime.store.finish(claim, "failed", error=from_error(exc))
        except MemoryError:
            runtime.store.finish(claim, "failed", error=memory_problem(settings.job_memory_mb))
        except Exception as exc:  # a bug: record it without a stack trace for clients
            log.exception("job %s (%s) crashed", claim.job_id, claim.kind)
            runtime.store.finish(claim, "failed",
                                 error=problem(500, "Job crashed", f"{type(exc).__name__}: {exc}"[:500]))
    finally:
        runtime.engine.dispose()
