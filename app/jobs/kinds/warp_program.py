"""Job ``warp_program``: an uploaded G-code program moved onto a measured surface.

The surface is a ``surface_fit`` job's NURBS surface (sampled) or a ``probe_run`` job's
measured points; see :mod:`app.circuits.warp` for what happens to each move.
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
from pydantic import Field, model_validator

from app.circuits.errors import WarpError
from app.circuits.gcode_scan import MIN_ARC_CHORD_MM, arc_chord_budget, scan_program
from app.circuits.height_model import height_model_from_points
from app.circuits.heightfield import points_region
from app.circuits.warp import WarpFigures, WarpOptions, check_region, fixed_split_error, warp_program
from app.domain.errors import InvalidInput
from app.gcode.program_bounds import BoundsScan
from app.geometry.nurbs_surface import NurbsSurface
from app.jobs.gcode_meta import gcode_meta
from app.jobs.params import StandoffMm
from app.jobs.results.models import ProbeRunResult, SurfaceFitResult
from app.jobs.results.program import WarpProgramResult
from app.platform.models import Job
from app.runtime.context import JobContext
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

#: the largest program the submission checks itself (lines, bytes, arc chords: ~0.5 s of CPU at most)
CHECK_LINES = 10_000
CHECK_BYTES = 2**20
CHECK_CHORDS = 10_000


class WarpProgramParams(JobParams):
    program_id: str = Field(description="an uploaded program (POST /api/v1/programs)")
    surface_fit_job_id: str | None = Field(None, description="a succeeded surface_fit job")
    probe_run_job_id: str | None = Field(None, description="a succeeded probe_run job (its measured points)")
    standoff_mm: StandoffMm | None = Field(None, description="printing moves at the surface + this; "
                                      "default: the program's z + the surface height")
    chord_error_mm: float = Field(0.002, gt=0, le=1, description="bound per emitted piece against the height model")
    arc_chord_mm: float = Field(0.001, ge=MIN_ARC_CHORD_MM, le=1,
                                description="G2/G3 arcs: largest top-view chord sagitta (the chords of all arcs "
                                            "together are bounded by the program's size)")
    clearance_mm: float = Field(2.0, gt=0, le=100, description="travel height above the surface's top")
    allow_outside: bool = Field(False, description="hold the edge height outside the measured region")
    grid_mm: float = Field(1.0, gt=0.05, le=20, description="height-field grid spacing")
    compare_split_mm: float = Field(5.0, gt=0, le=100, description="fixed split length reported beside ours")

    @model_validator(mode="after")
    def _one_surface(self) -> WarpProgramParams:
        if (self.surface_fit_job_id is None) == (self.probe_run_job_id is None):
            raise ValueError("give exactly one of surface_fit_job_id and probe_run_job_id")
        return self


def _surface_job(params: WarpProgramParams) -> tuple[str, str]:
    if params.surface_fit_job_id:
        return "surface_fit", params.surface_fit_job_id
    return "probe_run", str(params.probe_run_job_id)


def _check(params: WarpProgramParams, reads: JobReads) -> None:
    """The program must be readable, its arcs' chords within the budget, and (unless
    ``allow_outside``) print only inside the surface's measured region: a 422 naming the line
    and its coordinates before any job runs.  Bounded work in the request: a program beyond
    :data:`CHECK_LINES` lines or :data:`CHECK_BYTES` bytes, or whose arcs need more than
    :data:`CHECK_CHORDS` chords, is checked the same way by the job in its own process."""
    program = reads.program(params.program_id, field="params.program_id")
    kind, job_id = _surface_job(params)
    job = reads.succeeded_job(job_id, kind, f"params.{kind}_job_id")
    read_blob = reads.read_blob
    if read_blob is None:                     # a check without the store (never in the service)
        return
    if program.lines > CHECK_LINES or reads.blob_bytes(program.sha256) > CHECK_BYTES:
        return                                # the job checks it in its own process
    try:
        text = read_blob(program.sha256).decode("utf-8")
        arcs = BoundsScan("params.program_id", params.arc_chord_mm, arc_chord_budget(len(text)))
        arcs.block(text, 1)                   # the arcs' chords counted, none made
        if arcs.chords > CHECK_CHORDS:
            return
        recs = scan_program(text, params.arc_chord_mm)
        if not params.allow_outside:
            inside, bounds = points_region(_surface_points(job))
            check_region(recs, inside, bounds)
    except UnicodeDecodeError:
        raise InvalidInput("the program is not UTF-8 text", field="params.program_id", value=program.id) from None
    except (WarpError, InvalidInput) as exc:
        field = "params.arc_chord_mm" if exc.field == "arc_chord_mm" else "params.program_id"
        raise InvalidInput(f"program {program.name!r} {exc.message}", field=field, value=exc.value) from None


def _surface_points(job: Job) -> np.ndarray:
    if job.kind == "surface_fit":
        surface = NurbsSurface.from_dict(SurfaceFitResult.of(job).surface, field="surface")
        (u0, u1), (v0, v1) = surface.domain
        u, v = np.meshgrid(np.linspace(u0, u1, 60), np.linspace(v0, v1, 60), indexing="ij")
        return surface.evaluate(u.ravel(), v.ravel())
    return np.array([p.measured for p in ProbeRunResult.of(job).points], float)


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


@job_kind("warp_program", WarpProgramParams, check=_check,
          references=lambda p: [("job", _surface_job(p)[1])])
def run(ctx: JobContext, params: WarpProgramParams) -> dict:
    """Warp the program onto the surface; artifact ``warped.gcode``."""
    with ctx.reads() as reads:
        program = reads.program(params.program_id, field="params.program_id")
    text = ctx.blob(program.sha256).decode("utf-8")
    kind, job_id = _surface_job(params)
    field, model = height_model_from_points(
        _surface_points(ctx.job(job_id, kind=kind, field=f"params.{kind}_job_id")), params.grid_mm)
    ctx.progress(0.2, "warping")
    result = warp_program(text, field, WarpOptions(params.standoff_mm, params.chord_error_mm, params.clearance_mm,
                                                   allow_outside=params.allow_outside,
                                                   arc_chord_mm=params.arc_chord_mm))
    ctx.artifact("warped.gcode", result.text.encode(), "text/x-gcode", gcode_meta(result.text))
    pieces, worst = fixed_split_error(text, field, params.compare_split_mm, params.standoff_mm or 0.0)
    return WarpProgramResult.written({**{f.name: getattr(result, f.name) for f in fields(WarpFigures)},
            "model_error_mm": _finite(model.cv_max_mm),
            "height_model": {"kind": model.kind, "cv": model.cv, "cv_rms_mm": _finite(model.cv_rms_mm),
                             "cv_max_mm": _finite(model.cv_max_mm),
                             "alternatives": {k: _finite(v) for k, v in model.alternatives.items()},
                             "kriging": model.kriging, "posterior_sd_max_mm": model.posterior_sd_max_mm},
            "fixed_split": {"split_mm": params.compare_split_mm, "pieces": pieces, "max_error_mm": worst}})
