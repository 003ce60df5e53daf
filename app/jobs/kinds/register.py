"""Job ``register``: where the part really sits on the machine (dx, dy, dz, rz).

Plans datum touches on the part's nominal mesh (:func:`plan_datum_probes`), touches them
on the machine with -Z probes only (what every probing firmware can do, the mock
included): each side-face datum is found by bisecting across the nominal wall
(``mode="edges"``), top datums are touched at the points placed by the edges; then fits
the placement with its covariance (:func:`register_with_z_probe`).  ``mode="z_only"``
touches the top alone (sloped faces make dx, dy, rz observable, biased by a machining
error of a free-form top; a flat top gives dz only and says so in ``unobservable``).

The placement is part frame -> machine frame: rotation ``rz_deg`` about the vertical axis
through ``pivot`` (machine xy, default the origin, as the mock's placement), then
(dx, dy, dz).  Other jobs take it as ``registration_job_id`` or an explicit
``placement`` (:class:`app.jobs.params.PlacementParams`); :func:`app.jobs.inputs.placement_from`
resolves either.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from app.calibration import surface_heights
from app.jobs.params import RegisterParams
from app.jobs.probe_correction import machine_probe
from app.jobs.results.models import RegisterResult
from app.machines.live import hardware_errors, translate
from app.registration.datum_plan import plan_datum_probes, register_with_z_probe
from app.runtime.context import JobContext
from app.runtime.machine_queue import (
    interrupt,
    refuse_if_machine_busy,
    rehomed_machine,
    resume_request,
    stopped_by_operator,
)
from app.runtime.reads import JobReads
from app.runtime.registry import job_kind
from hardware.errors import HardwareError, LinkError


def _check(params: RegisterParams, reads: JobReads) -> None:
    reads.part(params.part_id, field="params.part_id")
    refuse_if_machine_busy(params.machine_id, reads)


@job_kind("register", RegisterParams, queue="machine", check=_check,
          references=lambda p: [("part", p.part_id), ("machine", p.machine_id)])
def run(ctx: JobContext, params: RegisterParams) -> dict[str, Any]:
    """Touch the datum features and fit the part's placement with its uncertainty."""
    mesh = ctx.mesh(params.part_id)
    ctx.progress(0.05, "planning datum touches")
    plan = plan_datum_probes(mesh, "sides" if params.mode == "edges" else "z_only", count=params.count,
                             margin_mm=params.margin_mm, seed=params.seed, sigma_mm=params.sigma_mm)
    resume = resume_request(ctx)
    state = {"total": None, "touches": 0, "resumes": (resume or {}).get("resumes", 0)}
    machine = rehomed_machine(ctx, params.machine_id, resume, state)
    probe = machine_probe(ctx, params.machine_id)
    tip_radius = params.tip_radius_mm if params.tip_radius_mm is not None else \
        (probe.calibration.ball_radius_mm if probe is not None else 0.0)
    surface_z = None
    if probe is not None:
        with hardware_errors():
            machine.select_tool(0)
        calibration = probe.calibration

        def surface_z(z_read: float, normal: np.ndarray) -> float:
            return float(surface_heights([[0.0, 0.0, z_read]], [normal], calibration).z_mm[0])
    z_bottom, z_top = mesh.bounds[:, 2]
    z_start, z_min = float(z_top) + params.clearance_mm, float(z_bottom) - params.overtravel_mm
    feed = params.probe_feed_mm_min
    touches = 0

    def probe_z(x: float, y: float) -> float:
        nonlocal touches
        try:
            touch = machine.probe(x, y, z_start=z_start, z_min=z_min, feed_mm_min=feed)
        except HardwareError as exc:
            state["touches"] = touches
            if isinstance(exc, LinkError) or stopped_by_operator(ctx, machine):
                raise interrupt(ctx, machine, exc, state) from exc
            raise translate(exc) from exc
        touches += 1
        if touches % 10 == 0:
            ctx.progress(min(0.9, 0.1 + touches / 100), f"{touches} datum touches")
        return touch.z

    with ctx.lease(params.machine_id):
        fitted = register_with_z_probe(plan, probe_z, float(z_bottom), params.probe_params(tip_radius),
                                       surface_z=surface_z)
    ctx.progress(0.95, f"placement fitted from {fitted.probe_count} touches")
    calibrated = {} if probe is None else {"calibration": {"probe_job_id": probe.job_id, "tip_radius_mm": tip_radius,
                                                            "probe": probe.calibration.to_dict()}}
    return RegisterResult.written({**fitted.to_result(), "mode": params.mode, **calibrated,
                                   "plan": {"faces": list(plan.faces), "predicted_std": {
                                       "rz_deg" if k == "rz" else f"{k}_mm": math.degrees(v) if k == "rz" else v
                                       for k, v in plan.predicted_std.items()}}})
