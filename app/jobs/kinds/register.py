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
``placement`` (:class:`PlacementParams`); :func:`placement_from` resolves either.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field, model_validator
from sqlmodel import Session

from app.compensation.datum_plan import DatumProbeParams, plan_datum_probes, register_with_z_probe
from app.compensation.registration import Placement
from app.errors import InvalidInput
from app.jobs.context import JobContext
from app.jobs.machine_jobs import (interrupt, refuse_if_machine_busy, rehomed_machine, resume_request,
                                   stopped_by_operator)
from app.jobs.registry import JobParams, job_kind
from app.calibration import surface_heights
from app.jobs.probe_correction import machine_probe
from app.machines import hardware_errors, translate
from hardware.errors import HardwareError, LinkError
from app.models import Job, Part
from app.records import get_or_404

Finite = Annotated[float, Field(allow_inf_nan=False, ge=-10_000, le=10_000)]


class PlacementParams(BaseModel):
    """A rigid placement of the part on the machine (what a ``register`` job reports)."""

    model_config = ConfigDict(extra="forbid")

    dx: float = Field(0.0, ge=-1000, le=1000, description="x translation, mm")
    dy: float = Field(0.0, ge=-1000, le=1000, description="y translation, mm")
    dz: float = Field(0.0, ge=-1000, le=1000, description="z translation, mm")
    rz_deg: float = Field(0.0, ge=-180, le=180, description="rotation about the vertical axis through pivot, degrees")
    pivot: list[Finite] = Field(default_factory=lambda: [0.0, 0.0], min_length=2, max_length=2,
                                description="rotation axis (machine x, y) mm")

    def to_placement(self) -> Placement:
        return Placement.from_deg(self.dx, self.dy, self.dz, self.rz_deg, (self.pivot[0], self.pivot[1]))


class PlacedParams(JobParams):
    """Parameters of jobs that can work in machine coordinates (a placed trace)."""

    placement: PlacementParams | None = Field(
        None, description="map the trace into machine coordinates with this placement before use")
    registration_job_id: str | None = Field(
        None, description="a succeeded register job whose placement maps the trace into machine coordinates")

    @model_validator(mode="after")
    def _one_placement(self) -> "PlacedParams":
        if self.placement is not None and self.registration_job_id is not None:
            raise ValueError("give at most one of placement or registration_job_id")
        return self


def registration_reference(params: PlacedParams) -> list[tuple[str, str]]:
    return [("job", params.registration_job_id)] if params.registration_job_id else []


def check_registration(params: PlacedParams, session: Session) -> Placement | None:
    """Submission check: the referenced job is a succeeded register job; its placement."""
    if params.registration_job_id is None:
        return None if params.placement is None else params.placement.to_placement()
    job = get_or_404(session, Job, params.registration_job_id, field="params.registration_job_id")
    if job.kind != "register" or job.status != "succeeded":
        raise InvalidInput(f"job {job.id!r} is a {job.status} {job.kind} job; a succeeded register job is needed",
                           field="params.registration_job_id", value=job.id)
    return PlacementParams.model_validate(job.result["placement"]).to_placement()


def placement_from(ctx: JobContext, params: PlacedParams) -> Placement | None:
    """The placement ``params`` asks for (explicit, or a register job's), else None."""
    if params.registration_job_id is not None:
        job = ctx.job(params.registration_job_id, kind="register", field="params.registration_job_id")
        return PlacementParams.model_validate(job.result["placement"]).to_placement()
    return None if params.placement is None else params.placement.to_placement()


def placed_mesh(mesh: trimesh.Trimesh, placement: Placement | None) -> trimesh.Trimesh:
    """The part mesh in machine coordinates (a copy; the mesh itself when no placement)."""
    if placement is None:
        return mesh
    placed = mesh.copy()
    placed.apply_transform(placement.matrix())
    return placed


class RegisterParams(JobParams):
    part_id: str
    machine_id: str
    mode: Literal["edges", "z_only"] = Field(
        "edges", description="edges: side faces found by -Z bisection across each wall + top heights "
        "(dx, dy, rz from planar walls); z_only: -Z touches on the top only")
    count: int | None = Field(None, ge=1, le=50, description="datum features to touch (default 6 edges, 8 z_only)")
    sigma_mm: float = Field(0.001, gt=0, le=1, description="probe repeatability (1 sigma)")
    search_mm: float = Field(1.5, gt=0, le=20, description="edge search half-width: the largest placement "
                             "error the edge search finds; below margin_mm")
    resolution_mm: float = Field(0.001, gt=0, le=1, description="edge bisection stops at this bracket")
    tip_radius_mm: float | None = Field(None, ge=0, le=5, description="probe ball radius (the top edge is caught "
                                        "early); default: the machine's calibrated ball radius, else 0")
    margin_mm: float = Field(2.0, gt=0, le=50, description="datum touches keep this far from face edges")
    pivot_xy: list[Finite] = Field(default_factory=lambda: [0.0, 0.0], min_length=2, max_length=2,
                                   description="rotation axis of the reported placement (machine x, y) mm")
    clearance_mm: float = Field(2.0, gt=0, le=100, description="travel height above the part's top")
    overtravel_mm: float = Field(1.0, gt=0, le=50, description="probe down to this far below the part's bottom")
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the machine profile's")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="seed of the candidate sampling (plans are deterministic)")

    @model_validator(mode="after")
    def _search_within_margin(self) -> "RegisterParams":
        if self.mode == "edges" and self.search_mm >= self.margin_mm:
            raise ValueError("search_mm must be below margin_mm (the edge search starts over the part)")
        return self


def _check(params: RegisterParams, session: Session) -> None:
    get_or_404(session, Part, params.part_id, field="params.part_id")
    refuse_if_machine_busy(params.machine_id, session)


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

    ctx.runtime.machines.running_job[params.machine_id] = ctx.job_id
    try:
        fitted = register_with_z_probe(plan, probe_z, float(z_bottom), DatumProbeParams(
            search_mm=params.search_mm, resolution_mm=params.resolution_mm, tip_radius_mm=tip_radius,
            sigma_mm=params.sigma_mm, pivot_xy=(params.pivot_xy[0], params.pivot_xy[1])), surface_z=surface_z)
    finally:
        ctx.runtime.machines.running_job.pop(params.machine_id, None)
    ctx.progress(0.95, f"placement fitted from {fitted.probe_count} touches")
    calibrated = {} if probe is None else {"calibration": {"probe_job_id": probe.job_id, "tip_radius_mm": tip_radius,
                                                            "probe": probe.calibration.to_dict()}}
    return {**fitted.to_result(), "mode": params.mode, **calibrated,
            "plan": {"faces": list(plan.faces), "predicted_std": {
                "rz_deg" if k == "rz" else f"{k}_mm": math.degrees(v) if k == "rz" else v
                for k, v in plan.predicted_std.items()}}}
