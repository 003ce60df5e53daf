"""Job ``reconstruct``: the real trace from measured probe points."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator
from sqlmodel import Session

from app.jobs.context import JobContext
from app.jobs.kinds.probe_plan import nominal_of
from app.jobs.registry import JobParams, job_kind
from app.models import Trace
from app.reconstruction import PreprocessParams, Reconstruction, ReconstructionError, preprocess, reconstruct
from app.records import get_or_404

DEGREE = 3

Finite = Annotated[float, Field(allow_inf_nan=False)]


class ReconstructJobParams(JobParams):
    trace_id: str
    probe_run_job_id: str | None = None
    points: list[Annotated[list[Finite], Field(min_length=3, max_length=3)]] | None = Field(
        None, max_length=100_000, description="measured points [[x, y, z], ...] mm, instead of a probe run")
    method: Literal["interpolate", "approximate", "deviation"] = Field(
        "interpolate", description="interpolate: the seed's cubic NURBS through the points; approximate: "
        "least squares; deviation: nominal + smoothed deviation (noise-aware, fewest probes)")
    sigma_mm: float | None = Field(None, ge=0, le=1, description="probe noise (1 sigma)")

    @model_validator(mode="after")
    def _one_source(self) -> "ReconstructJobParams":
        if (self.probe_run_job_id is None) == (self.points is None):
            raise ValueError("give exactly one of probe_run_job_id or points")
        return self


def _references(params: ReconstructJobParams) -> list[tuple[str, str]]:
    refs = [("trace", params.trace_id)]
    if params.probe_run_job_id:
        refs.append(("job", params.probe_run_job_id))
    return refs


def _check(params: ReconstructJobParams, session: Session) -> None:
    """Given points must be finite, near the trace and enough for the method after cleaning."""
    if params.points is None:
        return
    trace = get_or_404(session, Trace, params.trace_id, field="params.trace_id")
    clean = preprocess(nominal_of(trace), params.points, PreprocessParams(), field="params.points")
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
    return reconstruct(nominal_of(trace), measured, params.method, sigma_mm=params.sigma_mm)
