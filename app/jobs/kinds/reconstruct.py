"""Job ``reconstruct``: the real trace from measured probe points.

With ``placement`` or ``registration_job_id`` the trace's nominal is mapped into machine
coordinates first (as the probe plan that measured the points did); the reconstruction,
and so the ``compensate`` job that rebuilds it, is then in machine coordinates."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator
from sqlmodel import Session

from app.jobs.context import JobContext
from app.jobs.kinds.probe_plan import placed_nominal
from app.jobs.kinds.register import PlacedParams, check_registration, placement_from, registration_reference
from app.jobs.registry import job_kind
from app.models import Trace
from app.probing import PlanParams
from app.reconstruction import (PreprocessParams, Reconstruction, ReconstructionError, ReconstructParams,
                                preprocess, reconstruct)
from app.records import get_or_404

DEGREE = 3

Finite = Annotated[float, Field(allow_inf_nan=False)]


class ReconstructJobParams(PlacedParams):
    trace_id: str
    probe_run_job_id: str | None = None
    points: list[Annotated[list[Finite], Field(min_length=3, max_length=3)]] | None = Field(
        None, max_length=100_000, description="measured points [[x, y, z], ...] mm, instead of a probe run")
    method: Literal["interpolate", "approximate", "deviation", "kriging"] = Field(
        "interpolate", description="interpolate: the seed's cubic NURBS through the points; approximate: "
        "least squares; deviation: nominal + smoothed deviation (noise-aware); kriging: nominal + the "
        "best estimate of the deviation under the process model below (pair with the kriging planner)")
    sigma_mm: float | None = Field(None, ge=0, le=1, description="probe noise (1 sigma)")
    deviation_amplitude_mm: float = Field(0.2, gt=0, le=10, description="kriging: expected machining error amplitude")
    deviation_wavelength_mm: float = Field(20.0, gt=0, le=10_000,
                                           description="kriging: shortest wavelength of the machining error")

    @model_validator(mode="after")
    def _one_source(self) -> "ReconstructJobParams":
        if (self.probe_run_job_id is None) == (self.points is None):
            raise ValueError("give exactly one of probe_run_job_id or points")
        return self


def _references(params: ReconstructJobParams) -> list[tuple[str, str]]:
    refs = [("trace", params.trace_id), *registration_reference(params)]
    if params.probe_run_job_id:
        refs.append(("job", params.probe_run_job_id))
    return refs


def _check(params: ReconstructJobParams, session: Session) -> None:
    """Given points must be finite, near the (placed) trace and enough for the method after cleaning."""
    placement = check_registration(params, session)
    if params.points is None:
        return
    trace = get_or_404(session, Trace, params.trace_id, field="params.trace_id")
    clean = preprocess(placed_nominal(trace, placement), params.points, PreprocessParams(), field="params.points")
    if len(clean.s) < DEGREE + 1:
        raise ReconstructionError(
            f"params.points: {len(clean.s)} distinct usable points; a cubic reconstruction needs {DEGREE + 1}",
            field="params.points", value=len(clean.s))


@job_kind("reconstruct", ReconstructJobParams, references=_references, check=_check)
def run(ctx: JobContext, params: ReconstructJobParams) -> dict:
    """Rebuild the real trace from measured points (outliers rejected, duplicates merged)."""
    ctx.progress(0.2, "reconstructing")
    return rebuild(ctx, params).to_result()


def rebuild(ctx: JobContext, params: ReconstructJobParams) -> Reconstruction:
    """The reconstruction a ``reconstruct`` job with ``params`` makes (deterministic, so the
    ``compensate`` job rebuilds it from the stored parameters instead of storing objects)."""
    trace = ctx.trace(params.trace_id)
    if params.points is not None:
        measured = params.points
    else:
        probe_run = ctx.job(params.probe_run_job_id, kind="probe_run", field="params.probe_run_job_id")
        measured = [p["measured"] for p in probe_run.result["points"]]
    nominal = placed_nominal(trace, placement_from(ctx, params))
    prior = PlanParams(deviation_amplitude_mm=params.deviation_amplitude_mm,
                       deviation_wavelength_mm=params.deviation_wavelength_mm).prior()
    return reconstruct(nominal, measured, params.method, sigma_mm=params.sigma_mm,
                       params=ReconstructParams(prior=prior))
