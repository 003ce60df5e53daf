"""Job ``probe_run``: execute a probe plan on a machine and record the measured points.

Recovery: when the link drops mid-run, the job reconnects (up to ``reconnect_attempts``)
and touches the interrupted point again — a touch is idempotent, and every point before
it was already recorded.  A probe that finds no surface fails the job with a 422 naming
the point; no measured points are stored from a failed run.
"""

from __future__ import annotations

import time

import numpy as np
from pydantic import Field
from sqlmodel import Session

from app.jobs.context import JobContext
from app.jobs.machine_jobs import connected_machine, refuse_if_machine_busy
from app.jobs.registry import JobParams, job_kind
from app.machines import MachineUnavailable, hardware_errors
from hardware.errors import LinkError


class ProbeRunParams(JobParams):
    plan_job_id: str = Field(description="a succeeded probe_plan job")
    machine_id: str
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the plan's")
    reconnect_attempts: int = Field(3, ge=0, le=20, description="reconnects after a lost link before failing")


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
    reconnects = 0
    try:
        for index, record in enumerate(records):
            x, y, z_nominal = record["nominal"]
            while True:
                try:
                    if machine.link_lost:  # the link dropped after the previous touch
                        raise MachineUnavailable("link lost") from LinkError("link lost")
                    with hardware_errors():
                        touch = machine.probe(x, y, z_start=record["safe_z_mm"], z_min=record["target_z_mm"],
                                              feed_mm_min=feed)
                    break
                except MachineUnavailable as exc:
                    if not isinstance(exc.__cause__, LinkError) or reconnects >= params.reconnect_attempts:
                        raise
                    reconnects += 1
                    ctx.progress(index / len(records), f"link lost at point {index}; reconnecting ({reconnects})")
                    time.sleep(0.2 * reconnects)
                    machine = connected_machine(ctx, params.machine_id)
            points.append({"index": index, "nominal": [x, y, z_nominal], "measured": [touch.x, touch.y, touch.z],
                           "deviation_mm": touch.z - z_nominal})
            ctx.progress((index + 1) / len(records), f"probed {index + 1}/{len(records)}")
    finally:
        ctx.runtime.machines.running_job.pop(params.machine_id, None)
    deviations = np.array([p["deviation_mm"] for p in points])
    return {"points": points, "reconnects": reconnects, "stats": {"count": len(points), "max_abs_mm": float(np.abs(deviations).max()),
                                        "mean_mm": float(deviations.mean()),
                                        "rms_mm": float(np.sqrt(np.mean(deviations ** 2)))}}
