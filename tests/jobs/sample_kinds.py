"""Job kinds used by the platform tests (loaded through ``CONFORMA_JOB_PLUGINS``)."""

from __future__ import annotations

import time
from typing import Any, ClassVar

from pydantic import Field

from app.domain.errors import InvalidInput
from app.jobs.results.models import KindResult
from app.runtime.context import JobContext
from app.runtime.registry import JobParams, job_kind


class SleepParams(JobParams):
    seconds: float = Field(0.2, ge=0, le=120)
    steps: int = Field(4, ge=1, le=1000)
    artifact: bool = False


@job_kind("test_sleep", SleepParams)
def run_sleep(ctx: JobContext, params: SleepParams) -> dict:
    """Sleep in steps, reporting progress; optionally write an artifact."""
    for step in range(params.steps):
        time.sleep(params.seconds / params.steps)
        ctx.progress((step + 1) / params.steps, f"step {step + 1}/{params.steps}")
    if params.artifact:
        ctx.artifact("hello.txt", f"job {ctx.job_id} slept {params.seconds}\n".encode(), "text/plain")
    return {"slept_s": params.seconds, "attempt": ctx.claim.attempt}


class FailParams(JobParams):
    message: str = "boom"


@job_kind("test_fail", FailParams)
def run_fail(ctx: JobContext, params: FailParams) -> dict:
    """Fail with a domain error."""
    raise InvalidInput(params.message, field="params.message", value=params.message)


class HogParams(JobParams):
    mb: int = Field(100, ge=1, le=1_000_000)
    hold_s: float = Field(0.0, ge=0, le=120)


@job_kind("test_hog", HogParams)
def run_hog(ctx: JobContext, params: HogParams) -> dict:
    """Allocate and touch ``mb`` MiB in 16 MiB blocks (never reporting progress), then hold it."""
    import numpy as np

    blocks = [np.ones(2**21) for _ in range(max(1, params.mb // 16))]
    time.sleep(params.hold_s)
    return {"allocated_mb": 16 * len(blocks)}


class CrashParams(JobParams):
    signal: int = Field(9, ge=1, le=31)


@job_kind("test_crash", CrashParams)
def run_crash(ctx: JobContext, params: CrashParams) -> dict:
    """Kill the process running the job with a signal (a segfault, the OOM killer...)."""
    import os

    os.kill(os.getpid(), params.signal)
    time.sleep(10)
    return {}


class SpinParams(JobParams):
    seconds: float = Field(30, ge=0, le=600)
    later_seconds: float | None = Field(None, ge=0, le=600, description="the attempts after the first spin this "
                                        "long (default: seconds)")


@job_kind("test_spin", SpinParams)
def run_spin(ctx: JobContext, params: SpinParams) -> dict:
    """Busy-loop without ever checking for cancel (a long native loop)."""
    later = ctx.claim.attempt > 1 and params.later_seconds is not None
    deadline = time.monotonic() + (params.later_seconds if later else params.seconds)
    while time.monotonic() < deadline:
        pass
    return {}


class BlasParams(JobParams):
    pass


@job_kind("test_blas_threads", BlasParams)
def run_blas_threads(ctx: JobContext, params: BlasParams) -> dict:
    """The BLAS/OpenMP thread counts the job's process runs with (threadpoolctl's view)."""
    from threadpoolctl import threadpool_info

    return {"num_threads": sorted({int(pool["num_threads"]) for pool in threadpool_info()})}


class DrapeParams(JobParams):
    part_id: str
    xy: list[list[float]] = Field(min_length=2, max_length=1000)


@job_kind("test_drape", DrapeParams, references=lambda p: [("part", p.part_id)])
def run_drape(ctx: JobContext, params: DrapeParams) -> dict:
    """Drape a top-view polyline onto a part (edge grid) and cast rays down onto it (embree):
    the per-part precomputations a warm compute process keeps."""
    import hashlib

    import numpy as np

    from app.geometry.drape import drape_polyline, top_surface_z

    mesh = ctx.mesh(params.part_id)
    xy = np.asarray(params.xy, dtype=float)
    points = drape_polyline(mesh, xy).points
    top = top_surface_z(mesh, xy).z
    return {"points": points.tolist(), "top_z": top.tolist(),
            "sha256": hashlib.sha256(points.tobytes() + np.asarray(top).tobytes()).hexdigest()}


class StubbornParams(JobParams):
    journal: str = Field(max_length=500)
    stubborn_s: int = Field(60, ge=0, le=600)
    seconds: float = Field(0.5, ge=0, le=60)


def _alive(pid: int) -> bool:
    from app.runtime.process_identity import start_ticks

    return start_ticks(pid) is not None


@job_kind("test_stubborn", StubbornParams)
def run_stubborn(ctx: JobContext, params: StubbornParams) -> dict:
    """Journal each execution ("start <pid> <attempt> <earlier pids still alive>", "end <pid>")
    in the file ``journal``.  The first execution makes its process outlive its server: it
    drops its parent-death signal and then sleeps ``stubborn_s`` in native code holding the
    GIL, so that the thread watching the server never runs.  Later ones sleep ``seconds``."""
    import ctypes
    import os
    from pathlib import Path

    journal = Path(params.journal)
    lines = journal.read_text().splitlines() if journal.exists() else []
    earlier = [int(line.split()[1]) for line in lines if line.startswith("start ")]
    alive = [pid for pid in earlier if pid != os.getpid() and _alive(pid)]
    with journal.open("a") as f:
        f.write(f"start {os.getpid()} {ctx.claim.attempt} {','.join(map(str, alive)) or '-'}\n")
    if not earlier:
        ctypes.CDLL(None).prctl(1, 0, 0, 0, 0)  # PR_SET_PDEATHSIG: none
        ctypes.PyDLL(None).sleep(params.stubborn_s)  # PyDLL: the GIL stays held
    else:
        time.sleep(params.seconds)
    with journal.open("a") as f:
        f.write(f"end {os.getpid()}\n")
    return {"attempt": ctx.claim.attempt}


class BoardResultParams(JobParams):
    trace_ids: list[str] = Field(min_length=1, max_length=10_000)
    points: int = Field(100, ge=1, le=10_000)
    artifacts_per_trace: int = Field(2, ge=0, le=2)


class BoardLikeResult(KindResult):
    """A board-shaped result: one row per trace (``points`` (n, 3) mm each) and a worst figure."""

    kind: ClassVar[str] = "test_board_result"
    summary_fields: ClassVar[tuple[str, ...]] = ("deviation",)
    board: bool
    deviation: dict[str, float]
    traces: list[dict[str, Any]]


@job_kind("test_board_result", BoardResultParams)
def run_board_result(ctx: JobContext, params: BoardResultParams) -> dict:
    """A result the size of a board compensate's (``points`` points per trace) and
    ``artifacts_per_trace`` small programs per trace, as a board job writes them."""
    rows = [{"trace_id": t, "segments": params.points - 1,
             "points": [[i * 0.1, k * 0.01, 10.0 + 1e-4 * i] for i in range(params.points)]}
            for k, t in enumerate(params.trace_ids)]
    for t in params.trace_ids:
        for name in ("print", "nominal")[:params.artifacts_per_trace]:
            ctx.artifact(f"{name}.{t}.gcode", f"G1 X0 ; {t}\n".encode(), "text/x-gcode")
    return BoardLikeResult.written({"board": True, "deviation": {"max_mm": 0.002, "rms_mm": 0.001}, "traces": rows})
