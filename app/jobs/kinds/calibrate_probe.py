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

from app.calibration import fit_qualification, plan_qualification, plan_times
from app.domain.errors import InvalidInput
from app.jobs.calibration import agreement, latest_calibration_job, machine_profile, probe_values
from app.jobs.calibration_touch import Step, TouchRun, check_pad_room, travel_height
from app.jobs.results.calibration import CalibrateProbeResult
from app.runtime.context import JobContext
from app.runtime.machine_queue import refuse_if_machine_busy
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

CAP_RINGS_DEG = (0.0, 30.0, 50.0, 65.0, 75.0)
PLACE_TOLERANCE_MM = 1.0     # the sphere may sit this far from its nominal place (profile)
LOCATED_TOLERANCE_MM = 0.05  # ... and this far from where the locating touches found it


class CalibrateProbeParams(JobParams):
    machine_id: str
    cap_rings_deg: list[float] = Field(default_factory=lambda: list(CAP_RINGS_DEG), min_length=2, max_length=10,
                                       description="polar angles of the cap rings (0..75 deg): the steep rings "
                                       "separate the ball radius from the pre-travel")
    per_ring: int = Field(36, ge=3, le=72, description="vertical touches per cap ring of the sphere")
    equator: int = Field(192, ge=7, le=360, description="horizontal touches around the sphere's equator: they fix "
                         "r - p0, the term a vertical reading needs (its uncertainty falls as 1/sqrt(equator))")
    pad_touches: int = Field(8, ge=0, le=40, description="vertical touches on the reference pad (0: none), "
                             "0.5 mm apart along x")
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the machine profile's")


def _check(params: CalibrateProbeParams, reads: JobReads) -> None:
    row = reads.machine(params.machine_id, field="params.machine_id")
    reference = machine_profile(row).reference
    if reference is None or reference.sphere is None:
        raise InvalidInput(f"machine {params.machine_id!r} has no reference sphere in its profile "
                           "(profile.reference.sphere: centre_mm, diameter_mm): the probe is qualified on it",
                           field="profile.reference.sphere", value=params.machine_id)
    if reference.pad is not None and params.pad_touches:
        check_pad_room(reference.pad.size_mm, params.pad_touches)
    refuse_if_machine_busy(params.machine_id, reads)


@job_kind("calibrate_probe", CalibrateProbeParams, queue="machine", check=_check,
          references=lambda p: [("machine", p.machine_id)])
def run(ctx: JobContext, params: CalibrateProbeParams) -> dict:
    """Qualify the probe on the reference sphere: ball radius, pre-travel, sphere centre, pad reading."""
    profile = machine_profile(ctx.machine(params.machine_id))
    reference = profile.reference
    assert reference is not None and reference.sphere is not None  # _check refused a profile without one
    sphere, pad = reference.sphere, reference.pad
    radius = profile.tools.probe.ball_radius_mm if profile.tools is not None else 0.0
    feed = params.probe_feed_mm_min or profile.probe_feed_mm_min
    # locate the sphere first (it may sit ~1 mm off its nominal place): the steep cap rings
    # that separate the radius from the pre-travel are planned around the located centre
    locate = plan_qualification(tuple(sphere.centre_mm), sphere.diameter_mm, radius, None, cap_rings_deg=(0, 30),
                                per_ring=4, equator=8, place_tolerance_mm=PLACE_TOLERANCE_MM)
    ctx.progress(0.02, f"locating the reference sphere ({len(locate)} touches)")
    with TouchRun(ctx, params.machine_id, travel_z=travel_height(profile, radius), feed_mm_min=feed) as touching:
        located = touching.touch([Step(t, 0) for t in locate], "locate", "locating the sphere", (0.02, 0.2))
        rough = fit_qualification(locate, np.asarray(located, dtype=float), sphere.diameter_mm, lobing=False)
        touches = plan_qualification(rough.sphere_centre_mm, sphere.diameter_mm, radius,
                                     tuple(pad.centre_mm) if pad is not None and params.pad_touches else None,
                                     cap_rings_deg=tuple(params.cap_rings_deg), per_ring=params.per_ring,
                                     equator=params.equator, pad_touches=params.pad_touches or 3,
                                     place_tolerance_mm=LOCATED_TOLERANCE_MM)
        readings = touching.touch([Step(t, 0) for t in touches], "qualify", "qualification", (0.2, 0.9))
        touching.park()
    ctx.progress(0.92, "fitting radius and pre-travel")
    every, all_readings = (*locate, *touches), np.asarray(located + readings, dtype=float)
    times = None  # with pad touches at both ends, a linear Z drift during the run is fitted too
    if pad is not None and params.pad_touches >= 1:
        times = plan_times(every, all_readings, travel_z=touching.travel_z, travel_feed=profile.travel_feed_mm_min,
                           probe_feed=feed, start_mm=touching.origin)
    calibration = fit_qualification(every, all_readings, sphere.diameter_mm, times_s=times)
    with ctx.reads() as reads:
        previous = latest_calibration_job(reads, params.machine_id, "calibrate_probe")
    values, std = probe_values(calibration)
    return CalibrateProbeResult.written({**calibration.to_dict(), "agreement": agreement(previous, values, std),
            "nominal_ball_radius_mm": radius,
            "readings": [{**t.to_dict(), "reading_mm": r, **({"t_s": float(times[i])} if times is not None else {})}
                         for i, (t, r) in enumerate(zip(every, located + readings, strict=True))]})
