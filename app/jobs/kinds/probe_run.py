"""Job ``probe_run``: execute a probe plan on a machine and record the measured points.

Recovery: when the link drops mid-run (or the server dies) the job becomes ``interrupted``
with the points measured so far in ``program_state``; an operator's resume re-homes and
touches the interrupted point again — a touch is idempotent, and every point before it
was already recorded.  A probe that finds no surface fails the job with a 422 naming
the point; no measured points are stored from a failed run.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from sqlmodel import Session

from app.jobs.context import JobContext
from app.jobs.machine_jobs import (interrupt, refuse_if_machine_busy, rehomed_machine,
                                   resume_request, stopped_by_operator)
from app.jobs.registry import JobParams, job_kind
from app.machines import translate
from hardware.errors import HardwareError, LinkError


class ProbeRunParams(JobParams):
    plan_job_id: str = Field(description="a succeeded probe_plan job")
    machine_id: str
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the plan's")


def _check(params: ProbeRunParams, session: Session) -> None:
    refuse_if_machine_busy(params.machine_id, session)


@job_kind("probe_run", ProbeRunParams, queue="machine", check=_check,
          references=lambda p: [("job", p.plan_job_id), ("machine", p.machine_id)])
def run(ctx: JobContext, params: ProbeRunParams) -> dict:
    """Touch every planned point (travel at its safe height, probe down to its target)."""
    plan = ctx.job(params.plan_job_id, kind="probe_plan", field="params.plan_job_id")
    records = plan.result["records"]
    feed = params.probe_feed_mm_min or plan.params.get("probe_feed_mm_min", 100.0)
    resume = resume_request(ctx)
    points: list[dict] = list((resume or {}).get("points", []))
    state: dict = {"total": len(records), "executed": len(points), "points": points,
                   "resumes": (resume or {}).get("resumes", 0)}
    machine = rehomed_machine(ctx, params.machine_id, resume, state)
    ctx.runtime.machines.running_job[params.machine_id] = ctx.job_id
    try:
        for index in range(len(points), len(records)):
            x, y, z_nominal = records[index]["nominal"]
            try:
                if machine.link_lost:  # the link dropped after the previous touch
                    raise LinkError("link lost", field="port")
                touch = machine.probe(x, y, z_start=records[index]["safe_z_mm"],
                                      z_min=records[index]["target_z_mm"], feed_mm_min=feed)
            except LinkError as exc:  # a touch is idempotent: a resume touches this point again
                raise interrupt(ctx, machine, exc, state) from exc
            except HardwareError as exc:
                if stopped_by_operator(ctx, machine):
                    raise interrupt(ctx, machine, exc, state) from exc
                raise translate(exc) from exc
            points.append({"index": index, "nominal": [x, y, z_nominal], "measured": [touch.x, touch.y, touch.z],
                           "deviation_mm": touch.z - z_nominal})
            state["executed"] = len(points)
            ctx.runtime.store.save_program_state(ctx.claim, state)
            ctx.progress((index + 1) / len(records), f"probed {index + 1}/{len(records)}")
    finally:
        ctx.runtime.machines.running_job.pop(params.machine_id, None)
    deviations = np.array([p["deviation_mm"] for p in points])
    return {"points": points, "resumes": state["resumes"],
            "stats": {"count": len(points), "max_abs_mm": float(np.abs(deviations).max()),
                      "mean_mm": float(deviations.mean()), "rms_mm": float(np.sqrt(np.mean(deviations ** 2)))}}
