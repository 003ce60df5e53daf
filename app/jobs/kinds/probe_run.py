"""Job ``probe_run``: execute a probe plan on a machine and record the measured points."""

from __future__ import annotations

import numpy as np
from pydantic import Field
from sqlmodel import Session

from app.jobs.context import JobContext
from app.jobs.machine_jobs import connected_machine, refuse_if_machine_busy
from app.jobs.registry import JobParams, job_kind
from app.machines import hardware_errors


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
    machine = connected_machine(ctx, params.machine_id)
    ctx.runtime.machines.running_job[params.machine_id] = ctx.job_id
    points = []
    try:
        for index, record in enumerate(records):
            x, y, z_nominal = record["nominal"]
            with hardware_errors():
                touch = machine.probe(x, y, z_start=record["safe_z_mm"], z_min=record["target_z_mm"],
                                      feed_mm_min=feed)
            points.append({"index": index, "nominal": [x, y, z_nominal], "measured": [touch.x, touch.y, touch.z],
                           "deviation_mm": touch.z - z_nominal})
            ctx.progress((index + 1) / len(records), f"probed {index + 1}/{len(records)}")
    finally:
        ctx.runtime.machines.running_job.pop(params.machine_id, None)
    deviations = np.array([p["deviation_mm"] for p in points])
    return {"points": points, "stats": {"count": len(points), "max_abs_mm": float(np.abs(deviations).max()),
                                        "mean_mm": float(deviations.mean()),
                                        "rms_mm": float(np.sqrt(np.mean(deviations ** 2)))}}
