"""Job ``compensate``: the print program at the trace's standoff above the REAL surface.

Frame: the reconstruction's (rebuilt from the reconstruct job's parameters): when that
job mapped the trace with a placement / registration, the programs are in machine
coordinates.

Policy outside the probed span: refused (422) unless ``hold_mm`` allows holding the end
deviation over a short gap; see :mod:`app.compensation.standoff`.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from sqlmodel import Session

from app.compensation.standoff import CompensationParams, compensate_trace
from app.jobs.context import JobContext
from app.jobs.gcode_meta import gcode_meta
from app.jobs.kinds.reconstruct import ReconstructJobParams, rebuild
from app.jobs.kinds.register import placement_from
from app.jobs.registry import JobParams, job_kind
from app.models import Job, Machine
from app.records import get_or_404


class CompensateParams(JobParams):
    trace_id: str
    reconstruct_job_id: str = Field(description="a succeeded reconstruct job of this trace")
    standoff_mm: float | None = Field(None, gt=0, le=50, description="default: the trace's standoff")
    feed_mm_min: float | None = Field(None, gt=0, le=100_000, description="default: the trace's, else 300")
    chord_error_mm: float = Field(0.002, gt=0, le=1, description="largest polyline-to-curve distance, proved per segment")
    machine_id: str | None = Field(None, description="take dialect and dispense commands from this machine's profile")
    dialect: Literal["marlin", "grbl"] = "marlin"
    dispense_on: str = Field("M106", min_length=1, max_length=80, pattern=r"^[A-Za-z0-9 .\-]+$")
    dispense_off: str = Field("M107", min_length=1, max_length=80, pattern=r"^[A-Za-z0-9 .\-]+$")
    hold_mm: float = Field(0.0, ge=0, le=5, description="hold the end deviation over gaps to the probed span "
                           "up to this length (0: refuse moves outside the probed span)")
    clearance_mm: float = Field(2.0, gt=0, le=100)


def _check(params: CompensateParams, session: Session) -> None:
    job = get_or_404(session, Job, params.reconstruct_job_id, field="params.reconstruct_job_id")
    if job.kind != "reconstruct" or job.status != "succeeded" or job.params.get("trace_id") != params.trace_id:
        from app.errors import InvalidInput

        raise InvalidInput(f"job {job.id!r} is not a succeeded reconstruct job of trace {params.trace_id!r}",
                           field="params.reconstruct_job_id", value=job.id)


def _references(params: CompensateParams) -> list[tuple[str, str]]:
    refs = [("trace", params.trace_id), ("job", params.reconstruct_job_id)]
    if params.machine_id:
        refs.append(("machine", params.machine_id))
    return refs


@job_kind("compensate", CompensateParams, check=_check, references=_references)
def run(ctx: JobContext, params: CompensateParams) -> dict:
    """Regenerate the trace's print program above the reconstructed real surface."""
    trace = ctx.trace(params.trace_id)
    source = ctx.job(params.reconstruct_job_id, kind="reconstruct", field="params.reconstruct_job_id")
    rebuilt_params = ReconstructJobParams.model_validate(source.params)
    reconstruction = rebuild(ctx, rebuilt_params)
    ctx.progress(0.3, "segmenting the compensated path")
    dialect, on, off = params.dialect, params.dispense_on, params.dispense_off
    if params.machine_id:
        machine: Machine = ctx.machine(params.machine_id)
        dialect, on, off = machine.dialect, machine.profile["dispense_on"], machine.profile["dispense_off"]
    placement = placement_from(ctx, rebuilt_params)  # the reconstruction's frame (machine, when placed)
    mesh = ctx.runtime.meshes.placed(ctx.part(trace.part_id), placement)
    path = compensate_trace(reconstruction, CompensationParams(
        standoff_mm=params.standoff_mm or trace.standoff_mm,
        feed_mm_min=params.feed_mm_min or trace.feed_mm_min or 300.0,
        chord_error_mm=params.chord_error_mm, dispense_on=on, dispense_off=off, dialect=dialect,
        clearance_mm=params.clearance_mm, part_max_z_mm=float(mesh.bounds[1][2]), hold_mm=params.hold_mm,
    ), job_id=ctx.job_id)
    ctx.artifact("print.gcode", path.program.encode(), "text/x-gcode", gcode_meta(path.program))
    ctx.artifact("nominal.gcode", path.nominal_program.encode(), "text/x-gcode", gcode_meta(path.nominal_program))
    result = {**path.to_result(), "points": path.points.tolist()}
    if placement is not None:
        result["placement"] = placement.to_dict()
    return result
