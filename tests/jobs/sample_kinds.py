"""Job kinds used by the platform tests (loaded through ``CONFORMA_JOB_PLUGINS``)."""

from __future__ import annotations

import time

from pydantic import Field

from app.errors import InvalidInput
from app.jobs.context import JobContext
from app.jobs.registry import JobParams, job_kind


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
