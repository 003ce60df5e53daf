"""Job ``calibrate_probe``: qualify the touch probe (T0) on the machine's reference sphere.

Plans vertical touches on the sphere's cap, horizontal radial touches around its equator
and vertical touches on the reference pad (when the profile has one) from the profile's
NOMINAL places (:func:`app.calibration.plan_qualification`), touches them with the probe,
and fits the effective ball radius, the direction-dependent pre-travel, the sphere centre
and the pad reading with their uncertainties (:func:`app.calibration.fit_qualification`).
The result is the :class:`ProbeCalibration` dict plus ``agreement`` with the machine's
previous probe calibration and the raw ``readings``.  Leaves the machine retracted at T0.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from sqlmodel import Session

from app.calibration import fit_qualification, plan_qualification
from app.errors import InvalidInput
from app.jobs.calibration import agreement, latest_calibration_job, machine_profile, probe_values
from app.jobs.calibration_touch import Step, run_steps, travel_height
from app.jobs.context import JobContext
from app.jobs.machine_jobs import refuse_if_machine_busy
from app.jobs.registry import JobParams, job_kind
from app.models import Machine
from app.records import get_or_404


class CalibrateProbeParams(JobParams):
    machine_id: str
    per_ring: int = Field(8, ge=3, le=36, description="vertical touches per cap ring of the sphere")
    equator: int = Field(16, ge=4, le=72, description="horizontal touches around the sphere's equator")
    pad_touches: int = Field(3, ge=0, le=20, description="vertical touches on the reference pad (0: none)")
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the machine profile's")


def _check(params: CalibrateProbeParams, session: Session) -> None:
    row = get_or_404(session, Machine, params.machine_id, field="params.machine_id")
    reference = machine_profile(row).reference
    if reference is None or reference.sphere is None:
        raise InvalidInput(f"machine {params.machine_id!r} has no reference sphere in its profile "
                           "(profile.reference.sphere: centre_mm, diameter_mm): the probe is qualified on it",
                           field="profile.reference.sphere", value=params.machine_id)
    refuse_if_machine_busy(params.machine_id, session)


@job_kind("calibrate_probe", CalibrateProbeParams, queue="machine", check=_check,
          references=lambda p: [("machine", p.machine_id)])
def run(ctx: JobContext, params: CalibrateProbeParams) -> dict:
    """Qualify the probe on the reference sphere: ball radius, pre-travel, sphere centre, pad reading."""
    profile = machine_profile(ctx.machine(params.machine_id))
    sphere, pad = profile.reference.sphere, profile.reference.pad  # type: ignore[union-attr]
    radius = profile.tools.probe.ball_radius_mm if profile.tools is not None else 0.0
    touches = plan_qualification(tuple(sphere.centre_mm), sphere.diameter_mm, radius,
                                 tuple(pad.centre_mm) if pad is not None and params.pad_touches else None,
                                 per_ring=params.per_ring, equator=params.equator,
                                 pad_touches=params.pad_touches or 3)
    ctx.progress(0.02, f"{len(touches)} touches planned on the reference sphere"
                 + (" and pad" if pad is not None and params.pad_touches else ""))
    readings = run_steps(ctx, params.machine_id, [Step(t, 0) for t in touches],
                         travel_z=travel_height(profile, radius),
                         feed_mm_min=params.probe_feed_mm_min or profile.probe_feed_mm_min, label="qualification")
    ctx.progress(0.92, "fitting radius and pre-travel")
    calibration = fit_qualification(touches, np.asarray(readings, dtype=float), sphere.diameter_mm)
    with ctx.session() as session:
        previous = latest_calibration_job(session, params.machine_id, "calibrate_probe")
    values, std = probe_values(calibration)
    return {**calibration.to_dict(), "agreement": agreement(previous, values, std),
            "nominal_ball_radius_mm": radius,
            "readings": [{**t.to_dict(), "reading_mm": r} for t, r in zip(touches, readings, strict=True)]}
