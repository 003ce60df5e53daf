"""Job ``five_axis``: a nozzle-normal X Y Z A C program for a trace on a surface (the EHD patent's method).

* Surface: the ``surface_fit_job_id`` job's surface (the "real surface"), or else a fit of
  the part's nominal top surface over the trace's bounding region (grown by
  ``fit_margin_mm``, clipped to the part's footprint, sampled on a ``fit_grid`` grid,
  missing heights filled) — the result's ``surface_source`` says which.
* Trace: its stored nominal points' top view (x, y), draped onto that surface
  (:func:`app.five_axis.trace.trace_over_xy`).
* Plan: :func:`app.five_axis.plan_five_axis` — constant feed with the
  second-order Taylor parameter update at ``period_s`` (first order measured beside it),
  nozzle along the surface normal (or the patent's principal normal, ``normal``), a
  table-tilting A (about X) / C (about Z) machine with the table pivot ``pivot``; X Y Z are
  the nozzle tip in machine coordinates, ``m = Rx(A) Rz(C) (p - pivot) + pivot``.
* Singularity: within ``pole_window_deg`` of A = 0 the core blends C instead of following
  the normal's azimuth, and splits program lines until the tip stays within
  ``midpoint_tol_mm`` of its planned path between lines (result ``max_midpoint_error_mm``).
* Artifacts ``five_axis.gcode`` and the three-axis ``nominal.gcode`` (nozzle straight
  above the contact points), written by the core: ``dispense_on`` follows the approach
  move to the first pose and ``dispense_off`` the last move, so every G1 between them
  dispenses.

* Post-processor ``post``: ``conforma`` (X Y Z = tip in machine coordinates) or
  ``linuxcnc_xyzac_trt`` (LinuxCNC TCP, ``M428``, X Y Z = tip in workpiece coordinates),
  see :mod:`app.five_axis.post`.  With ``machine_id`` the machine profile's
  dispense codes, program end, ``five_axis_post``, ``pivot_mm`` and the machine's dialect
  replace the job's own fields.

A pose needing A beyond ``a_limits_deg`` fails the job with a 422 problem naming
``params.a_limits_deg``.  Units: mm, mm/min and degrees at this boundary.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Any, NamedTuple

import numpy as np
from pydantic import Field, field_validator

from app.domain.errors import InvalidInput
from app.five_axis import FiveAxisError, FiveAxisParams, plan_five_axis
from app.five_axis.contact import NormalSource
from app.five_axis.errors import TraceOffSurfaceError
from app.five_axis.post import PostName
from app.five_axis.program import FeedMode
from app.five_axis.trace import plan_view_points, trace_over_xy, uv_over_xy
from app.gcode.writer import DEFAULT_PROBING_DIALECT, DialectName, own_dispense
from app.gcode.writer import DIALECTS as GCODE_DIALECTS
from app.geometry.nurbs_surface import NurbsSurface
from app.jobs.core_fields import core_field, core_values
from app.jobs.gcode_meta import gcode_meta
from app.jobs.inputs import nominal_of
from app.jobs.params import StandoffMm, standoff_of
from app.jobs.results.five_axis import FiveAxisResult
from app.jobs.results.models import SurfaceFitResult
from app.platform.models import Job, Machine, Part, Trace
from app.probing.grid import ProbeRegion, plan_probe_grid
from app.reconstruction.surface_fit import SurfaceFitParams, fit_part_top
from app.runtime.context import JobContext
from app.runtime.cost import Cost
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

_DISPENSE_COMMAND = r"^[A-Z][0-9]+(\.[0-9]+)?( [A-Z]-?[0-9]+(\.[0-9]+)?)*$"
# FiveAxisParams fields this job does not expose (the core's defaults); every other core field
# has this job's parameter's name, so a core error's ``params.<name>`` is this job's parameter
CORE_ONLY = frozenset({"normal_side", "max_split_rounds", "job_id"})

_CORE = FiveAxisParams()  # the core's defaults are this job's
_OWN_DISPENSE = own_dispense(DEFAULT_PROBING_DIALECT)  # grbl's M8 / M9
Finite = Annotated[float, Field(allow_inf_nan=False)]
Angle = Annotated[float, Field(ge=-180, le=180, allow_inf_nan=False)]


class FiveAxisJobParams(JobParams):
    part_id: str = Field(description="the part that carries the trace")
    trace_id: str = Field(description="a trace of the part (its nominal top view is followed)")
    surface_fit_job_id: str | None = Field(
        None, description="a succeeded surface_fit job of the part: its surface is the real surface; "
        "default: a fit of the part's nominal top over the trace's region")
    standoff_mm: StandoffMm | None = Field(None, description="nozzle height h above the surface along the "
                                           "nozzle axis; default: the trace's")
    feed_mm_min: float | None = Field(None, gt=0, le=100_000, description="print speed along the trace; "
                                      f"default: the trace's, else {_CORE.feed_mm_min:g}")
    period_s: float = core_field(FiveAxisParams, "period_s", description="servo period T of the Taylor update")
    segment_mm: float = core_field(FiveAxisParams, "segment_mm", description="program line spacing along the trace")
    pivot: list[Finite] = Field(list(_CORE.pivot), min_length=3, max_length=3,
                                description="table pivot [x0, y0, z0] mm (workpiece coordinates at A = C = 0)")
    normal: NormalSource = Field(
        _CORE.normal, description="nozzle direction: surface normal, or the trace's principal normal (patent)")
    a_limits_deg: list[Angle] = Field(list(_CORE.a_limits_deg), min_length=2, max_length=2,
                                      description="[min, max] table tilt A")
    c_limits_deg: list[Finite] | None = Field(None, min_length=2, max_length=2,
                                              description="[min, max] C; default endless")
    c_start_deg: float = core_field(FiveAxisParams, "c_start_deg", description="C before the path (biases the "
                                    "first branch; held if the whole path is within the pole window)")
    pole_window_deg: float = core_field(FiveAxisParams, "pole_window_deg", description="within this tilt of the "
                                        "normal from vertical (A = 0) C is blended smoothly and the nozzle may lean "
                                        "from the normal by at most this angle; 0 = exact normals")
    midpoint_tol_mm: float = core_field(FiveAxisParams, "midpoint_tol_mm", description="max tip deviation from its "
                                        "planned path halfway between program lines (longer lines are split)")
    feed_mode: FeedMode = Field(
        _CORE.feed_mode, description="inverse_time: G93, F = 1/minutes per line; tcp: G94, F = tip mm/min")
    on_surface_tol_mm: float = core_field(FiveAxisParams, "on_surface_tol_mm",
                                          description="max distance of the trace from the surface")
    decimals: int = core_field(FiveAxisParams, "decimals", description="digits of mm and degrees in the program")
    safe_z_mm: float | None = core_field(FiveAxisParams, "safe_z_mm", description="machine Z of the approach "
                                         "rapids; default: straight approach move")
    approach_feed_mm_min: float = core_field(FiveAxisParams, "approach_feed_mm_min",
                                             description="feed of the approach move")
    dispense_on: str = Field(_OWN_DISPENSE[0], max_length=40, pattern=_DISPENSE_COMMAND,
                             description="command that starts dispensing (after the approach)")
    dispense_off: str = Field(_OWN_DISPENSE[1], max_length=40, pattern=_DISPENSE_COMMAND,
                              description="command that stops dispensing (after the last move)")
    post: PostName = Field(
        _CORE.post, description="conforma: X Y Z = tip in machine coordinates (any controller; LinuxCNC "
        "xyzac-trt in identity mode); linuxcnc_xyzac_trt: M428 TCP, X Y Z = tip in workpiece coordinates")
    program_end: str | None = Field(None, max_length=40, pattern=_DISPENSE_COMMAND,
                                    description="the machine's program end, e.g. M2; default: the dialect's")
    dialect: DialectName = Field(DEFAULT_PROBING_DIALECT, description="G-code dialect of the program")
    machine_id: str | None = Field(None, description="take the dialect, dispense codes, program end, post and "
                                   "pivot (when set) from this machine's profile instead of the fields above")
    fit_grid: list[Annotated[int, Field(ge=4, le=100)]] = Field(
        [20, 20], min_length=2, max_length=2, description="without surface_fit_job_id: grid [nu, nv] "
        "of the nominal top fit")
    fit_margin_mm: float = Field(1.0, gt=0, le=100, description="without surface_fit_job_id: margin "
                                 "around the trace's bounding box")

    @field_validator("a_limits_deg")
    @classmethod
    def _a_ordered(cls, value: list[float]) -> list[float]:
        if value[0] > value[1]:
            raise ValueError("a_limits_deg must be [min, max] with min <= max")
        return value

    @field_validator("c_limits_deg")
    @classmethod
    def _c_ordered(cls, value: list[float] | None) -> list[float] | None:
        if value is not None and value[0] >= value[1]:
            raise ValueError("c_limits_deg must be [min, max] with min < max")
        return value

    def plan_params(self, trace: Trace, job_id: str | None) -> FiveAxisParams:
        """The core's parameters, field by field of the same name (lists as tuples); standoff
        and feed default to the trace's."""
        return FiveAxisParams(**core_values(
            FiveAxisParams, self, CORE_ONLY, job_id=job_id,
            standoff_mm=standoff_of(self.standoff_mm, trace.standoff_mm),
            feed_mm_min=self.feed_mm_min or trace.feed_mm_min or _CORE.feed_mm_min))


def with_machine(params: FiveAxisJobParams, machine: Machine) -> FiveAxisJobParams:
    """The parameters with the machine profile's program settings filled in."""
    profile = machine.profile or {}
    update: dict[str, Any] = {key: profile[key] for key in ("dispense_on", "dispense_off", "program_end")
                              if profile.get(key)}
    update["post"] = profile.get("five_axis_post") or _CORE.post
    if profile.get("pivot_mm") is not None:
        update["pivot"] = [float(v) for v in profile["pivot_mm"]]
    known = GCODE_DIALECTS.get(machine.dialect)  # a dialect the program writer knows
    if known is not None:
        update["dialect"] = known.name
    return params.model_copy(update=update)


def _in_params(exc: FiveAxisError) -> FiveAxisError:
    """The core's error naming this job's input: ``params.<name>`` is this job's parameter of the
    same name already; the core's ``trace`` input (and its parts, ``trace.xy``...) is the trace
    of ``params.trace_id``."""
    field = exc.field or ""
    if field == "trace" or field.startswith("trace."):
        return type(exc)(exc.message, field="params.trace_id", value=exc.value)
    return exc


def trace_xy(trace: Trace) -> np.ndarray:
    """Top view (k, 2) mm of the trace's stored nominal points, made fit for interpolation by
    :func:`app.five_axis.trace.plan_view_points` (a degenerate top view names ``params.trace_id``)."""
    try:
        return plan_view_points(nominal_of(trace).points[:, :2])
    except FiveAxisError as exc:
        raise _in_params(exc) from None


def _fitted_surface(job: Job, field: str) -> NurbsSurface:
    return NurbsSurface.from_dict(SurfaceFitResult.of(job).surface, field=field)


def _check(params: FiveAxisJobParams, reads: JobReads) -> None:
    """At submission: the trace belongs to the part, the surface_fit job is a succeeded fit
    of the same part, and the trace lies over its surface."""
    trace = reads.trace(params.trace_id, field="params.trace_id")
    if params.machine_id is not None:
        params = with_machine(params, reads.machine(params.machine_id, field="params.machine_id"))
    if trace.part_id != params.part_id:
        raise InvalidInput(f"trace {trace.id!r} belongs to part {trace.part_id!r}, not {params.part_id!r}",
                           field="params.trace_id", value=params.trace_id)
    try:
        params.plan_params(trace, None)
    except FiveAxisError as exc:
        raise _in_params(exc) from None
    if params.surface_fit_job_id is None:
        return
    field = "params.surface_fit_job_id"
    job = reads.succeeded_job(params.surface_fit_job_id, "surface_fit", field)
    if job.params.get("part_id") != params.part_id:
        raise InvalidInput(f"surface_fit job {job.id!r} fitted part {job.params.get('part_id')!r}, "
                           f"not {params.part_id!r}", field=field, value=job.id)
    try:
        uv_over_xy(_fitted_surface(job, field), trace_xy(trace))
    except TraceOffSurfaceError as exc:
        raise TraceOffSurfaceError(f"the trace leaves the surface of surface_fit job {job.id!r}: {exc.message}",
                                   field="params.trace_id", value=exc.value) from None


def _trace_region(xy: np.ndarray, margin_mm: float, part: Part) -> ProbeRegion:
    """The trace's top-view bounding box grown by ``margin_mm``, within the part's footprint."""
    (x_lo, y_lo, _), (x_hi, y_hi, _) = part.bounds
    lo, hi = xy.min(axis=0) - margin_mm, xy.max(axis=0) + margin_mm
    return ProbeRegion(max(float(lo[0]), x_lo), min(float(hi[0]), x_hi),
                       max(float(lo[1]), y_lo), min(float(hi[1]), y_hi))


class ChosenSurface(NamedTuple):
    """The surface to print on and where it came from (JSON-friendly description)."""

    surface: NurbsSurface
    source: dict[str, Any]


def _surface(ctx: JobContext, params: FiveAxisJobParams, xy: np.ndarray) -> ChosenSurface:
    """The surface_fit job's surface, or a fit of the part's nominal top around the trace."""
    if params.surface_fit_job_id is not None:
        field = "params.surface_fit_job_id"
        job = ctx.job(params.surface_fit_job_id, kind="surface_fit", field=field)
        return ChosenSurface(_fitted_surface(job, field), {"kind": "surface_fit", "job_id": job.id})
    region = _trace_region(xy, params.fit_margin_mm, ctx.part(params.part_id))
    plan = plan_probe_grid(region, params.fit_grid[0], params.fit_grid[1])
    fit = fit_part_top(ctx.mesh(params.part_id), plan, SurfaceFitParams(hole_policy="fill"))
    return ChosenSurface(fit.surface, {
        "kind": "nominal_top", "region": {"x": [region.x_min, region.x_max], "y": [region.y_min, region.y_max]},
        "grid": list(params.fit_grid), "filled_holes": fit.filled_holes,
        "residual": {"max_mm": fit.residual_max_mm, "rms_mm": fit.residual_rms_mm}})


# Cost model: the interpolation keeps every servo sample (length / (feed T)) with its parameter,
# position, derivatives and the quadrature of the feed fluctuation, ~SAMPLE_BYTES each; program
# lines (length / segment_mm) with their contact, normal and angles ~LINE_BYTES each.
SAMPLE_BYTES = 600.0
SAMPLE_S = 20e-6
LINE_BYTES = 2000.0
LINE_S = 200e-6
BASE_MB = 60.0


def _estimate(params: FiveAxisJobParams, reads: JobReads) -> Cost | None:
    """Predicted memory and time from the trace length, the feed, the servo period and the
    line spacing; names params.period_s (or params.segment_mm, params.feed_mm_min)."""
    trace = reads.find_trace(params.trace_id)
    if trace is None:
        return None
    feed = params.feed_mm_min or trace.feed_mm_min or _CORE.feed_mm_min
    samples = trace.length_mm / (feed / 60.0) / params.period_s
    lines = trace.length_mm / params.segment_mm
    sample_mb, line_mb = SAMPLE_BYTES * samples / 2**20, LINE_BYTES * lines / 2**20
    if sample_mb >= line_mb:
        field, value = (("params.period_s", params.period_s) if params.feed_mm_min is None
                        or params.period_s < 1e-3 else ("params.feed_mm_min", params.feed_mm_min))
    else:
        field, value = "params.segment_mm", params.segment_mm
    return Cost(memory_mb=BASE_MB + sample_mb + line_mb, time_s=SAMPLE_S * samples + LINE_S * lines,
                field=field, value=value,
                basis=f"{samples:,.0f} servo samples and {lines:,.0f} program lines over {trace.length_mm:g} mm")


@job_kind("five_axis", FiveAxisJobParams, check=_check, estimate=_estimate, references=lambda p: [
    ("part", p.part_id), ("trace", p.trace_id), *([("job", p.surface_fit_job_id)] if p.surface_fit_job_id else []),
    *([("machine", p.machine_id)] if p.machine_id else [])])
def run(ctx: JobContext, params: FiveAxisJobParams) -> dict:
    """Plan a nozzle-normal five-axis (X Y Z A C) traverse of a trace and write its program."""
    trace = ctx.trace(params.trace_id)
    if params.machine_id is not None:
        params = with_machine(params, ctx.machine(params.machine_id))
    plan_params = params.plan_params(trace, ctx.job_id)
    xy = trace_xy(trace)
    ctx.progress(0.05, "loading the surface")
    surface, source = _surface(ctx, params, xy)
    ctx.progress(0.3, f"surface from {source['kind']}; planning {trace.length_mm:.1f} mm of trace")
    try:
        path = plan_five_axis(surface, trace_over_xy(surface, xy), plan_params)
    except FiveAxisError as exc:
        raise _in_params(exc) from None
    ctx.progress(0.9, f"{path.u.size} poses; writing the programs")
    metas = {}
    for name, text in (("five_axis.gcode", path.program), ("nominal.gcode", path.nominal_program)):
        metas[name] = gcode_meta(text)
        ctx.artifact(name, text.encode(), "text/x-gcode", metas[name])
    return FiveAxisResult.written({
        **asdict(path.figures),
        "dispense_on": params.dispense_on,
        "dispense_off": params.dispense_off,
        "post": params.post,
        "standoff_mm": plan_params.standoff_mm,
        "feed_mm_min": plan_params.feed_mm_min,
        "feed_mode": plan_params.feed_mode,
        "pivot": list(plan_params.pivot),
        "surface_source": source,
        "surface": surface.to_dict(),
        "offset_curve": path.offset_curve.to_dict(),
        "program": metas["five_axis.gcode"],
        "nominal_program": metas["nominal.gcode"],
    })
