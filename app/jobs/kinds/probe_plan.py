"""Job ``probe_plan``: where to probe a trace, and the probe program (G-code).

With ``placement`` or ``registration_job_id`` the trace (and the part, for safe travel
heights) is first mapped into machine coordinates, so the probes land on the part where
it really sits; without, the part frame is the machine frame (unchanged behaviour)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field, model_validator
from sqlmodel import Session

from app.compensation.registration import Placement, place_path
from app.jobs.context import JobContext
from app.jobs.gcode_meta import gcode_meta
from app.jobs.kinds.register import (
    PlacedParams,
    check_registration,
    placed_mesh,
    placement_from,
    registration_reference,
)
from app.jobs.registry import job_kind
from app.models import Trace
from app.probing import NominalPath, PlanParams, ProbeProgramParams, build_probe_program, plan_probes
from app.probing.nominal import as_nominal_path


class ProbePlanParams(PlacedParams):
    trace_id: str
    method: Literal["adaptive", "uniform", "deviation", "kriging"] = Field(
        "adaptive", description="adaptive: the seed's chord-height rule; uniform: even arc length; "
        "deviation: spacing from the expected deviation of the real part from CAD; kriging: stations that "
        "minimise the largest predicted error of the deviation (machining error + placement), fewest probes")
    chord_error_mm: float = Field(0.005, gt=0, le=10)
    count: int | None = Field(None, ge=4, le=10_000, description="probe count (uniform/deviation)")
    capability_k: float | None = Field(None, gt=0, lt=1, description="seed eq. 1: process capability K")
    confidence: float | None = Field(None, gt=0.5, lt=1, description="seed eq. 1: confidence gamma")
    cl_tolerance_mm: float = Field(0.001, gt=0, le=1)
    deviation_amplitude_mm: float = Field(0.2, gt=0, le=10)
    deviation_wavelength_mm: float = Field(20.0, gt=0, le=10_000)
    target_error_mm: float = Field(0.005, gt=0, le=10)
    probe_sigma_mm: float = Field(0.001, ge=0, le=1)
    clearance_mm: float = Field(2.0, gt=0, le=100)
    approach_mm: float = Field(1.0, gt=0, le=50)
    overtravel_mm: float = Field(1.0, gt=0, le=50)
    probe_feed_mm_min: float = Field(100.0, gt=0, le=10_000)
    dialect: Literal["grbl", "marlin"] = "grbl"
    probe_style: Literal["g38", "g30"] | None = Field(None, description="default: G38.2 on grbl, G30 on Marlin")

    @model_validator(mode="after")
    def _both_or_neither(self) -> "ProbePlanParams":
        if (self.capability_k is None) != (self.confidence is None):
            raise ValueError("capability_k and confidence go together (seed eq. 1)")
        return self


@dataclass(frozen=True)
class StoredNominal:
    """A trace's stored draped polyline: points (k, 3) mm and unit normals (k, 3)."""

    points: np.ndarray
    normals: np.ndarray | None


def nominal_of(trace: Trace) -> NominalPath:
    """The stored draped nominal polyline of a trace as the planners' NominalPath."""
    normals = trace.nominal.get("normals")
    stored = StoredNominal(np.asarray(trace.nominal["points"], dtype=float),
                           None if normals is None else np.asarray(normals, dtype=float))
    return as_nominal_path(stored, field="trace.nominal")


def placed_nominal(trace: Trace, placement: Placement | None) -> NominalPath:
    """The trace's nominal in machine coordinates (unchanged without a placement)."""
    nominal = nominal_of(trace)
    return nominal if placement is None else place_path(nominal, placement)


def _check(params: ProbePlanParams, session: Session) -> None:
    check_registration(params, session)


@job_kind("probe_plan", ProbePlanParams, check=_check,
          references=lambda p: [("trace", p.trace_id), *registration_reference(p)])
def run(ctx: JobContext, params: ProbePlanParams) -> dict:
    """Plan probe points along a trace (placed into machine coordinates when asked) and
    write the probe program."""
    trace = ctx.trace(params.trace_id)
    placement = placement_from(ctx, params)
    mesh = placed_mesh(ctx.mesh(trace.part_id), placement)
    ctx.progress(0.1, "planning probe points")
    plan = plan_probes(placed_nominal(trace, placement), params.method, PlanParams(
        chord_error_mm=params.chord_error_mm, cl_tolerance_mm=params.cl_tolerance_mm, count=params.count,
        capability_k=params.capability_k, confidence=params.confidence,
        deviation_amplitude_mm=params.deviation_amplitude_mm, deviation_wavelength_mm=params.deviation_wavelength_mm,
        target_error_mm=params.target_error_mm, probe_sigma_mm=params.probe_sigma_mm,
    ))
    ctx.progress(0.5, f"{plan.count} probe points; writing the program")
    program = build_probe_program(plan, mesh, ProbeProgramParams(
        dialect=params.dialect, probe_style=params.probe_style, clearance_mm=params.clearance_mm,
        approach_mm=params.approach_mm, overtravel_mm=params.overtravel_mm,
        probe_feed_mm_min=params.probe_feed_mm_min, part_max_z_mm=float(mesh.bounds[1][2]),
    ), job_id=ctx.job_id)
    meta = gcode_meta(program.gcode)
    ctx.artifact("probe.gcode", program.gcode.encode(), "text/x-gcode", meta)
    result = {
        "count": plan.count,
        "method": plan.method,
        "points": plan.points.tolist(),
        "s_mm": plan.s_mm.tolist(),
        "records": [r.to_dict() for r in program.records],
        "spacing_mm": plan.spacing_mm,
        "trace_length_mm": trace.length_mm,
        "program": meta,
    }
    if placement is not None:
        result["placement"] = placement.to_dict()
    if plan.point_count is not None:
        result["point_count"] = {"count": plan.point_count.count, "n_exact": plan.point_count.n_exact,
                                 "z_gamma": plan.point_count.z_gamma}
    return result
