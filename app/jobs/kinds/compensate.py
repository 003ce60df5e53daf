"""Job ``compensate``: the print program at the trace's standoff above the REAL surface.

Frame: the reconstruction's (read back from the reconstruct job's stored
``reconstruction.npz``, over the trace's nominal placed as that job placed it): when that
job mapped the trace with a placement / registration, the programs are in machine
coordinates.  Board mode (``trace_ids``, from a board reconstruct job): each trace's
reconstruction is read back from its own artifact (``reconstruction.<trace_id>.npz``,
:func:`app.reconstruction.stored.stored_name`), nothing is rebuilt; each trace's programs
are ``print.<trace_id>.gcode`` / ``nominal.<trace_id>.gcode``.

Policy outside the probed span: refused (422) unless ``hold_mm`` allows holding the end
deviation over a short gap; see :mod:`app.compensation.standoff`.

Tool frame: on a machine whose profile has nozzles the programs are written for
a nozzle (``tool``, default the profile's first): ``T<tool>`` first, every coordinate the
carriage's = desired tip - the nozzle's CALIBRATED offset (the latest ``calibrate_nozzle``
job, :func:`app.jobs.calibration.current_calibration`).  An uncalibrated nozzle is refused
(422 ``params.tool``) unless ``allow_uncalibrated`` (nominal offset, with a warning);
``corrections.offsets: false`` uses the nominal offset on purpose (ablation).  The result's
``tool`` names the nozzle, the offset used and the calibration job.

Nozzle clearance: the nozzle body (a flat-ended cylinder of the profile's outer diameter)
is checked along the compensated path against the real surface (the placed nominal mesh +
the reconstructed deviation at the trace's nearest station); ``clearance`` reports the
smallest gap, and a body that would touch the part refuses the program (422 ``params.tool``
naming the trace, where and by how much).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from app.calibration.clearance import nozzle_clearance
from app.compensation.standoff import (
    CompensationError,
    CompensationParams,
    compensate_trace,
    real_surface_height,
    tip_path,
)
from app.domain.errors import InvalidInput
from app.gcode.writer import DEFAULT_DIALECT, own_dispense_text
from app.geometry.drape import top_surface_z
from app.geometry.traces import TracePolyline
from app.jobs.board_checkpoints import Output, TraceCheckpoints, inputs_sha256, trace_inputs
from app.jobs.core_fields import core_bounds, core_field, core_values
from app.jobs.form_hints import ONE_TRACE, SEVERAL_TRACES, form
from app.jobs.gcode_meta import gcode_meta
from app.jobs.held_reconstructions import stored_reconstruction
from app.jobs.inputs import placed_nominal, placed_nominals, placed_params_of, placement_from
from app.jobs.params import MAX_FIELD_TRACES, DispensingDialect, StandoffMm, standoff_of
from app.jobs.results.models import CompensateBoardResult, CompensateResult
from app.jobs.tool_choice import ToolChoice, choose_tool
from app.platform.models import Machine
from app.reconstruction.stored import read_reconstruction, stored_name
from app.runtime.context import JobContext
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

CLEARANCE_STEP_MM = 0.05  # tip stations of the nozzle-body check along the path
_CORE = CompensationParams()  # the core's defaults are this kind's
# CompensationParams fields this job does not expose (the core's defaults); the others are this
# job's parameters of the same name or derived in the job (standoff, feed, dispenser, tool)
CORE_ONLY = frozenset({"approach_mm", "plunge_feed_mm_min", "dwell_s", "span_tolerance_mm", "max_deviation_mm",
                       "verify_step_mm", "curvature_safety", "decimals", "xy_uncertainty_mm"})
_COMMAND = r"^[A-Za-z0-9 .\-]+$"  # one G-code line
_OWN_ON, _OWN_OFF = own_dispense_text(0), own_dispense_text(1)


class CompensateCorrections(BaseModel):
    """Which calibrations the program uses (false: that correction left out, for ablation)."""

    model_config = ConfigDict(extra="forbid")
    offsets: bool = Field(True, description="false: the nozzle's NOMINAL offset (the profile's) instead of "
                          "the calibrated one")


class CompensateParams(JobParams):
    trace_id: str | None = Field(None, description="the trace (or trace_ids)", json_schema_extra=ONE_TRACE)
    trace_ids: list[str] | None = Field(
        None, min_length=1, max_length=MAX_FIELD_TRACES,
        description="board mode: compensate these traces in ONE job from a board reconstruct job (reconstruct "
        "with trace_ids); each trace's programs are the artifacts print.<trace_id>.gcode and "
        "nominal.<trace_id>.gcode, the result's traces lists each trace's figures in this order",
        json_schema_extra=SEVERAL_TRACES)
    reconstruct_job_id: str = Field(description="a succeeded reconstruct job of this trace (board mode: of these "
                                    "traces)")
    standoff_mm: StandoffMm | None = Field(None, description="default: the trace's standoff")
    feed_mm_min: float | None = Field(None, **core_bounds(CompensationParams, "feed_mm_min"),
                                      description=f"default: the trace's, else {_CORE.feed_mm_min:g}")
    chord_error_mm: float = core_field(CompensationParams, "chord_error_mm",
                                       description="largest polyline-to-curve distance, proved per segment")
    machine_id: str | None = Field(None, description="take dialect and dispense commands from this machine's profile")
    dialect: DispensingDialect = Field(DEFAULT_DIALECT, description="G-code dialect of the programs (without "
                                       "machine_id)")
    dispense_on: str | None = Field(None, min_length=1, max_length=80, pattern=_COMMAND,
                                    description=f"without machine_id; default: the dialect's ({_OWN_ON})",
                                    json_schema_extra=form(advanced=True))
    dispense_off: str | None = Field(None, min_length=1, max_length=80, pattern=_COMMAND,
                                     description=f"without machine_id; default: the dialect's ({_OWN_OFF})",
                                     json_schema_extra=form(advanced=True))
    hold_mm: float = core_field(CompensationParams, "hold_mm", description="hold the end deviation over gaps to the "
                                "probed span up to this length (0: refuse moves outside the probed span)")
    clearance_mm: float = core_field(CompensationParams, "clearance_mm", json_schema_extra=form(advanced=True))
    tool: int | None = Field(None, ge=0, le=8, description="the nozzle T<tool> the programs are written for "
                             "(default: the machine profile's first nozzle; none: the probe frame); 0 = the "
                             "probe's frame with T0")
    allow_uncalibrated: bool = Field(False, description="write for a nozzle without calibration, at its "
                                     "nominal offset (a warning in the result)")
    corrections: CompensateCorrections = Field(default_factory=CompensateCorrections,
                                               json_schema_extra=form(advanced=True))

    @model_validator(mode="after")
    def _one_target(self) -> CompensateParams:
        if (self.trace_id is None) == (self.trace_ids is None):
            raise ValueError("give exactly one of trace_id or trace_ids")
        if self.trace_ids is not None and len(set(self.trace_ids)) != len(self.trace_ids):
            raise ValueError("trace_ids lists a trace twice")
        return self


def board_artifacts(trace_id: str) -> tuple[str, str]:
    """(print, nominal) artifact names of one trace of a board compensate job."""
    return f"print.{trace_id}.gcode", f"nominal.{trace_id}.gcode"


def _check(params: CompensateParams, reads: JobReads) -> None:
    job = reads.succeeded_job(params.reconstruct_job_id, "reconstruct", "params.reconstruct_job_id")
    if params.trace_ids is not None:
        rebuilt = set(job.params.get("trace_ids") or ())
        missing = [t for t in params.trace_ids if t not in rebuilt]
        if missing:
            raise InvalidInput(f"job {job.id!r} is not a board reconstruct job (trace_ids) of trace {missing[0]!r}",
                               field="params.reconstruct_job_id", value=job.id)
    elif job.params.get("trace_id") != params.trace_id:
        raise InvalidInput(f"job {job.id!r} is not a succeeded reconstruct job of trace {params.trace_id!r}",
                           field="params.reconstruct_job_id", value=job.id)
    names = [stored_name(t) for t in params.trace_ids] if params.trace_ids is not None else [stored_name()]
    stored = reads.artifact_names(job.id, names)
    lacking = next((name for name in names if name not in stored), None)
    if lacking is not None:
        raise InvalidInput(f"reconstruct job {job.id!r} has no stored reconstruction ({lacking}: it ran before "
                           "reconstructions were stored); run the reconstruction again",
                           field="params.reconstruct_job_id", value=job.id)
    choose_tool(reads, params.machine_id, params.tool, offsets=params.corrections.offsets,
                allow_uncalibrated=params.allow_uncalibrated)


def _references(params: CompensateParams) -> list[tuple[str, str]]:
    refs = [*(("trace", t) for t in (params.trace_ids or [str(params.trace_id)])), ("job", params.reconstruct_job_id)]
    if params.machine_id:
        refs.append(("machine", params.machine_id))
    return refs


@job_kind("compensate", CompensateParams, check=_check, references=_references)
def run(ctx: JobContext, params: CompensateParams) -> dict:
    """Regenerate the trace's print program above the reconstructed real surface (board
    mode: every listed trace's, each from its reconstruction the board reconstruct stored)."""
    source = ctx.job(params.reconstruct_job_id, kind="reconstruct", field="params.reconstruct_job_id")
    placement = placement_from(ctx, placed_params_of(source))  # the reconstruction's frame (machine, when placed)
    with ctx.reads() as reads:
        choice = choose_tool(reads, params.machine_id, params.tool, offsets=params.corrections.offsets,
                             allow_uncalibrated=params.allow_uncalibrated)
    if params.trace_ids is None:
        trace = ctx.trace(str(params.trace_id))
        reconstruction = read_reconstruction(ctx.artifact_bytes(source.id, stored_name()),
                                             placed_nominal(trace, placement))
        ctx.progress(0.3, "segmenting the compensated path")
        result, path = _program(ctx, params, choice, trace, reconstruction, placement)
        ctx.artifact("print.gcode", path.program.encode(), "text/x-gcode", _meta(path.program, path.program_bounds))
        ctx.artifact("nominal.gcode", path.nominal_program.encode(), "text/x-gcode",
                     _meta(path.nominal_program, path.nominal_program_bounds))
        return CompensateResult.written(result)
    rows = []
    total = len(params.trace_ids)
    checkpoints = TraceCheckpoints(ctx)
    shared = inputs_sha256(_board_inputs(ctx, params, choice, source.id, placement))
    stored = ctx.artifacts_of([(source.id, stored_name(t)) for t in params.trace_ids])  # one query
    records = _Records(ctx)
    traces = ctx.traces(params.trace_ids, nominals=False)  # one query, not one per trace
    for index, (trace, nominal) in enumerate(zip(traces, placed_nominals(ctx, traces, placement))):
        artifact = stored[(source.id, stored_name(trace.id))]
        inputs = inputs_sha256(shared, trace_inputs(trace, records.part(trace.part_id).sha256), artifact.sha256)
        row = checkpoints.reusable(trace.id, inputs)
        if row is None:
            row, outputs = _board_trace(ctx, params, choice, trace, nominal, artifact.sha256, placement, records)
            checkpoints.add(trace.id, inputs, outputs, row)  # stored with the group's checkpoint, one commit
        rows.append(row)
        if index % 25 == 24 or index + 1 == total:
            ctx.progress((index + 1) / total, f"{index + 1}/{total} traces compensated{checkpoints.note()}")
    checkpoints.flush()
    return CompensateBoardResult.written({"board": True, "traces": rows})


def _board_inputs(ctx: JobContext, params: CompensateParams, choice: ToolChoice, source_id: str,
                  placement: Any) -> dict[str, Any]:
    """What every trace's programs of a board job are made from besides the trace itself (the
    per-trace checkpoints' inputs, :mod:`app.jobs.board_checkpoints`): the parameters, the
    tool, the machine's dialect and dispense commands, the placement (each trace adds its
    record and its stored reconstruction's sha256)."""
    machine = None
    if params.machine_id:
        row = ctx.machine(params.machine_id)
        machine = {"dialect": row.dialect, "dispense_on": row.profile.get("dispense_on"),
                   "dispense_off": row.profile.get("dispense_off")}
    return {"kind": "compensate", "params": params.model_dump(mode="json", exclude={"trace_ids"}),
            "tool": choice.to_result(), "warnings": choice.warnings,
            "dispense": [choice.dispense_on, choice.dispense_off],
            "machine": machine, "placement": None if placement is None else placement.to_dict(),
            "reconstruct_job_id": source_id}


class _Records:
    """A board job's machine and parts, each read once (not once per trace)."""

    def __init__(self, ctx: JobContext) -> None:
        self.ctx = ctx
        self._machines: dict[str, Machine] = {}
        self._parts: dict[str, Any] = {}

    def machine(self, machine_id: str) -> Machine:
        if machine_id not in self._machines:
            self._machines[machine_id] = self.ctx.machine(machine_id)
        return self._machines[machine_id]

    def part(self, part_id: str) -> Any:
        if part_id not in self._parts:
            self._parts[part_id] = self.ctx.part(part_id)
        return self._parts[part_id]


def _board_trace(ctx: JobContext, params: CompensateParams, choice: ToolChoice, trace: Any, nominal: TracePolyline,
                 stored: str, placement: Any, records: _Records) -> tuple[dict[str, Any], list[Output]]:
    """Compensate one trace of a board job (its placed ``nominal``) from its ``stored``
    reconstruction (the sha256 of its npz bytes: held in this process by the reconstruct job
    that stored them, else read, :func:`app.jobs.held_reconstructions.stored_reconstruction`):
    its result row and its two programs as artifacts to store."""
    reconstruction = stored_reconstruction(stored, lambda: ctx.blob(stored), nominal)
    result, path = _program(ctx, params, choice, trace, reconstruction, placement, records)
    printed, plain = board_artifacts(trace.id)
    outputs: list[Output] = [(printed, path.program.encode(), "text/x-gcode", _meta(path.program, path.program_bounds)),
                             (plain, path.nominal_program.encode(), "text/x-gcode",
                              _meta(path.nominal_program, path.nominal_program_bounds))]
    return {"trace_id": trace.id, "print_artifact": printed, "nominal_artifact": plain, **result}, outputs


def _meta(program: str, bounds: list[list[float]] | None) -> dict[str, Any]:
    """A program's G-code meta, its bounds the writer's own when it followed every line (the
    moves are then not read again: reading them cost more than compensating the trace)."""
    return gcode_meta(program, bounds=bounds)


def _program(ctx: JobContext, params: CompensateParams, choice: ToolChoice, trace: Any, reconstruction: Any,
             placement: Any, records: _Records | None = None) -> tuple[dict[str, Any], Any]:
    """(result, the compensated path with its programs) of one trace (``records``: a board
    job's machine and parts, read once for all its traces)."""
    dialect: str = params.dialect
    on, off = params.dispense_on, params.dispense_off
    if params.machine_id:
        machine: Machine = records.machine(params.machine_id) if records else ctx.machine(params.machine_id)
        dialect, on, off = machine.dialect, machine.profile["dispense_on"], machine.profile["dispense_off"]
        on, off = choice.dispense_on or on, choice.dispense_off or off
    mesh = ctx.placed_mesh(records.part(trace.part_id) if records else ctx.part(trace.part_id), placement)
    path = compensate_trace(reconstruction, CompensationParams(**core_values(
        CompensationParams, params, CORE_ONLY,
        standoff_mm=standoff_of(params.standoff_mm, trace.standoff_mm),
        feed_mm_min=params.feed_mm_min or trace.feed_mm_min or _CORE.feed_mm_min,
        dispense_on=on, dispense_off=off, dialect=dialect,
        part_max_z_mm=float(mesh.bounds[1][2]), tool=choice.tool, tool_offset_mm=choice.offset_mm,
    )), job_id=ctx.job_id)
    clearance = None
    if choice.tool and choice.outer_diameter_mm:
        if params.trace_ids is None:
            ctx.progress(0.7, "checking the nozzle body's clearance")
        clearance = _clearance(trace, reconstruction, path, mesh, choice.outer_diameter_mm)
    result = {**path.to_result(), "points": path.points.tolist(), "tool": choice.to_result(),
              "warnings": choice.warnings}
    if clearance is not None:
        result["clearance"] = clearance
    if placement is not None:
        result["placement"] = placement.to_dict()
    return result, path


def _clearance(trace: Any, reconstruction: Any, path: Any, mesh: Any, diameter_mm: float) -> dict[str, Any]:
    """``{min_mm, s_mm, point_mm, outer_diameter_mm}`` of the nozzle body along the compensated
    tip path (stations every CLEARANCE_STEP_MM); CompensationError (422 ``params.tool``) when
    the body would touch the part."""
    length = float(reconstruction.nominal.length_mm)
    s = np.linspace(0.0, length, max(2, int(np.ceil(length / CLEARANCE_STEP_MM)) + 1))
    tips = tip_path(reconstruction, s, path.standoff_mm, path.span)
    height = real_surface_height(lambda xy: top_surface_z(mesh, xy).z, reconstruction, path.span,
                                 floor_mm=float(mesh.bounds[0][2]))
    found = nozzle_clearance(tips, height, diameter_mm)
    at = float(s[found.index])
    point = [round(float(v), 4) for v in found.point_mm]
    report = {"min_mm": round(float(found.min_mm), 6), "s_mm": round(at, 4), "point_mm": point,
              "outer_diameter_mm": diameter_mm}
    if found.min_mm <= 0.0:
        raise CompensationError(
            f"trace {trace.name} ({trace.id}): the nozzle body (outer diameter {diameter_mm:g} mm) would touch "
            f"the part at s = {at:.3f} mm ({point[0]:.3f}, {point[1]:.3f}, {point[2]:.3f}) by "
            f"{-found.min_mm:.4f} mm; no program produced (a thinner nozzle, a larger standoff, or a flatter "
            f"path)", field="params.tool", value={"trace_id": trace.id, "trace": trace.name, "s_mm": round(at, 4),
                                                    "point_mm": point, "by_mm": round(-float(found.min_mm), 6)})
    return report
