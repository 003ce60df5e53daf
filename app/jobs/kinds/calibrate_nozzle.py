"""Job ``calibrate_nozzle``: measure nozzle T<tool>'s offset to the probe.

Z: the probe (T0) touches the reference pad, then the nozzle's flat end touches the same
pad (touch-off); the offset's Z is the pad surface in the probe frame (reading + the
calibrated pre-travel - ball radius) minus the nozzle's pad reading.  XY: the nozzle body's
side touches the reference sphere from opposite directions; the sphere centre known in the
probe frame (from the current probe calibration) minus the midpoint of those readings
(:func:`app.calibration.plan_nozzle_calibration`, :func:`app.calibration.fit_nozzle_offset`).
Two stages: "locate" (one pad spot, one side touch each way, the full approach for the
nominal offset's doubt) gives a rough offset and pad height; "offset" (the full 2-D pad grid
and the side touches) then starts every touch ``LOCATED_CLEARANCE_MM`` from its contact.
Needs a current probe calibration (422 "calibrate the probe first"), the tool in the
profile's nozzles and the reference pad and sphere.  The result is the
:class:`NozzleCalibration` dict plus ``nominal_difference_mm`` (calibrated - nominal),
``probe_job_id`` (the probe calibration it rests on), ``agreement`` with the tool's
previous calibration and the raw ``readings``.  Leaves the machine retracted at T0.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from app.calibration import fit_nozzle_offset, plan_nozzle_calibration
from app.domain.errors import InvalidInput
from app.jobs.calibration import (
    agreement,
    latest_calibration_job,
    machine_profile,
    nozzle_values,
    require_probe_calibration,
)
from app.jobs.calibration_touch import Step, TouchRun, check_pad_room, travel_height
from app.jobs.results.calibration import CalibrateNozzleResult
from app.runtime.context import JobContext
from app.runtime.machine_queue import refuse_if_machine_busy
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

LOCATED_CLEARANCE_MM = 0.3   # approach after locating: the located offset is good to microns, the pad flat

class CalibrateNozzleParams(JobParams):
    machine_id: str
    tool: int = Field(ge=1, le=8, description="the nozzle's tool number (T1..T8, in the machine profile)")
    pad_touches: int = Field(144, ge=1, le=400, description="spots on the pad (a 2-D grid 0.5 mm apart) touched by "
                             "the probe and by the nozzle: the Z offset's uncertainty falls with their number")
    side_touches: int = Field(12, ge=1, le=32, description="pairs of opposite side touches of the nozzle on the "
                              "sphere: the XY offset's uncertainty falls with their number")
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the machine profile's")


def _nozzle(params: CalibrateNozzleParams, profile):
    nozzles = profile.tools.nozzles if profile.tools is not None else []
    for nozzle in nozzles:
        if nozzle.tool == params.tool:
            return nozzle
    known = ", ".join(f"T{n.tool}" for n in nozzles) or "none"
    raise InvalidInput(f"tool T{params.tool} is not a nozzle of machine {params.machine_id!r} "
                       f"(profile.tools.nozzles: {known})", field="params.tool", value=params.tool)


def _check(params: CalibrateNozzleParams, reads: JobReads) -> None:
    row = reads.machine(params.machine_id, field="params.machine_id")
    profile = machine_profile(row)
    _nozzle(params, profile)
    for name in ("pad", "sphere"):
        if profile.reference is None or getattr(profile.reference, name) is None:
            raise InvalidInput(f"machine {params.machine_id!r} has no reference {name} in its profile "
                               f"(profile.reference.{name}): nozzle offsets are measured on the pad and sphere",
                               field=f"profile.reference.{name}", value=params.machine_id)
    check_pad_room(profile.reference.pad.size_mm, params.pad_touches, grid=True)  # type: ignore[union-attr]
    require_probe_calibration(reads, params.machine_id)
    refuse_if_machine_busy(params.machine_id, reads)


@job_kind("calibrate_nozzle", CalibrateNozzleParams, queue="machine", check=_check,
          references=lambda p: [("machine", p.machine_id)])
def run(ctx: JobContext, params: CalibrateNozzleParams) -> dict:
    """Measure a nozzle's XYZ offset to the probe (Z by touch-off on the pad, XY on the sphere)."""
    profile = machine_profile(ctx.machine(params.machine_id))
    nozzle = _nozzle(params, profile)
    reference = profile.reference
    assert reference is not None and reference.sphere is not None and reference.pad is not None  # _check's rule
    sphere, pad = reference.sphere, reference.pad
    with ctx.reads() as reads:
        current = require_probe_calibration(reads, params.machine_id)
    probe = current.probe
    assert probe is not None  # require_probe_calibration
    # locate first (one pad spot, one touch per side, the full clearance for the nominal offset's doubt),
    # then the many touches with a short approach from the located offset and pad height
    locate = plan_nozzle_calibration(probe, tuple(nozzle.offset_mm), nozzle.outer_diameter_mm, sphere.diameter_mm,
                                     tuple(pad.centre_mm), pad_touches=1, side_touches=1)
    ctx.progress(0.02, f"locating T{params.tool} ({len(locate)} touches)")
    with TouchRun(ctx, params.machine_id, travel_z=travel_height(profile, probe.ball_radius_mm),
                  feed_mm_min=params.probe_feed_mm_min or profile.probe_feed_mm_min) as touching:
        located = touching.touch([Step(t, 0 if t.kind == "pad" else params.tool) for t in locate], "locate",
                                 f"locating T{params.tool}", (0.02, 0.1))
        rough = fit_nozzle_offset(params.tool, locate, np.asarray(located, dtype=float), probe,
                                  nozzle.outer_diameter_mm, sphere.diameter_mm)
        pad_z = located[0][2] + float(probe.pretravel.at([[0.0, 0.0, 1.0]])[0]) - probe.ball_radius_mm
        touches = plan_nozzle_calibration(probe, rough.offset_mm, nozzle.outer_diameter_mm, sphere.diameter_mm,
                                          tuple(pad.centre_mm), pad_touches=params.pad_touches,
                                          side_touches=params.side_touches, clearance_mm=LOCATED_CLEARANCE_MM,
                                          pad_z_mm=pad_z)
        steps = [Step(t, 0 if t.kind == "pad" else params.tool) for t in touches]
        readings = touching.touch(steps, "offset", f"T{params.tool} offset", (0.1, 0.9))
        touching.park()
    ctx.progress(0.92, f"fitting T{params.tool}'s offset")
    calibration = fit_nozzle_offset(params.tool, touches, np.asarray(readings, dtype=float), probe,
                                    nozzle.outer_diameter_mm, sphere.diameter_mm)
    with ctx.reads() as reads:
        previous = latest_calibration_job(reads, params.machine_id, "calibrate_nozzle", params.tool)
    values, std = nozzle_values(calibration)
    return CalibrateNozzleResult.written({**calibration.to_dict(), "agreement": agreement(previous, values, std),
            "nominal_offset_mm": list(nozzle.offset_mm),
            "nominal_difference_mm": [float(c - n) for c, n in zip(calibration.offset_mm, nozzle.offset_mm,
                                                                   strict=True)],
            "probe_job_id": current.probe_job_id,
            "readings": [{**t.to_dict(), "tool": s.tool, "reading_mm": r}
                         for t, s, r in zip(touches, steps, readings, strict=True)]})
