"""Job ``toolpath``: fill paths for the layers of a slice job, G-code and its print time.

The layers come from the slice job's ``layers.npz`` artifact (exactly the contours of its
``layers.json``, beam compensation included, as arrays; ``layers.json`` itself for a slice
job stored before it wrote one); nothing is re-sliced.  ``time_s`` is the
estimate of the written ``print.gcode`` by :func:`app.gcode.estimator.estimate_gcode` with
the machine limits below (so anyone can re-run it on the downloaded file; the job takes
the moves from the writer, :func:`app.gcode.fdm.write_fdm_program`, which records exactly
what the reader reads from that text, rather than reading it back);
``planner_time_s`` is the fill planner's own estimate of the extruded and travel moves
alone (no retracts, homing or start section).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from app.domain.errors import ConformaError
from app.gcode.estimator import MachineLimits, estimate_program
from app.gcode.fdm import END_LIFT_MM, FdmMode, FdmParams, write_fdm_program
from app.gcode.placement import BedPlacement, MachineVolume, check_inside, placement_shift
from app.gcode.writer import DEFAULT_DIALECT, own_dispense_text
from app.gcode.writer import DIALECTS as GCODE_DIALECTS
from app.jobs.core_fields import core_field, core_values
from app.jobs.form_hints import form
from app.jobs.gcode_meta import gcode_meta
from app.jobs.params import DispensingDialect
from app.jobs.results.models import SliceResult
from app.jobs.results.program import ToolpathResult
from app.platform.models import Machine
from app.runtime.context import JobContext
from app.runtime.cost import Cost
from app.runtime.heap import HEAP_TOP_KEEP_BYTES
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind
from app.slicing import SlicingError, ToolpathParams
from app.slicing.export import from_json
from app.slicing.export_binary import NAME as BINARY_LAYERS
from app.slicing.export_binary import from_binary
from app.slicing.fractal import MergeWeights
from app.slicing.layers import SliceResult as SlicedLayers
from app.slicing.layers import translated
from app.slicing.toolpath import THINNEST_WALL, LayerStats, LayerToolpath, PathCounts, Pattern, iter_toolpath, totals_of

MM_MIN_PER_MM_S = 60.0
_FILL = ToolpathParams()
_LIMITS = MachineLimits()
_FDM = FdmParams()
_DEFAULT_ON, _DEFAULT_OFF = own_dispense_text(0), own_dispense_text(1)

Speed = Annotated[float, Field(gt=0, le=10_000, allow_inf_nan=False)]
Accel = Annotated[float, Field(gt=0, le=1_000_000, allow_inf_nan=False)]
# form hints (app.jobs.form_hints): folded fields, and the fields of one mode or pattern only
_MORE = form(advanced=True)
_EXTRUDE = form(when={"mode": ["extrude"]})
_EXTRUDE_MORE = form(when={"mode": ["extrude"]}, advanced=True)
_DISPENSE_MORE = form(when={"mode": ["dispense"]}, advanced=True)
_MERGED = form(advanced=True, when={"pattern": ["hilbert_merged"]})
Command = Annotated[str, Field(min_length=1, max_length=60, pattern=r"^[A-Za-z0-9 .\-]+$")]


def _mm_min(mm_s: float) -> float:
    return mm_s * MM_MIN_PER_MM_S


Finite = Annotated[float, Field(ge=-10_000, le=10_000, allow_inf_nan=False)]
Travel = Annotated[list[Finite], Field(min_length=2, max_length=2)]


class VolumeIn(BaseModel):
    """A machine's travel limits, mm: [min, max] per axis."""

    model_config = ConfigDict(extra="forbid")
    x: Travel
    y: Travel
    z: Travel

    @model_validator(mode="after")
    def _ordered(self) -> VolumeIn:
        for axis in "xyz":
            lo, hi = getattr(self, axis)
            if not hi > lo:
                raise ValueError(f"volume_mm.{axis}: the maximum must exceed the minimum")
        return self

    def volume(self, source: str) -> MachineVolume:
        return MachineVolume(tuple(self.x), tuple(self.y), tuple(self.z), source)  # type: ignore[arg-type]


class PlacementIn(BaseModel):
    """How the part goes onto the bed (the slice is in the part's own frame)."""

    model_config = ConfigDict(extra="forbid")
    xy: Literal["center", "offset", "as_is"] = Field(
        "center", description="center: the part's bounding box centred on the bed; offset: its minimum corner at "
        "offset_mm; as_is: keep the part's own x, y")
    offset_mm: tuple[Finite, Finite] = Field((0.0, 0.0), description="xy: offset - bed position of the part's "
                                             "minimum x, y corner, mm")
    drop_to_bed: bool = Field(True, description="put the part's lowest point on the bed (the volume's z minimum)")

    def core(self) -> BedPlacement:
        return BedPlacement(self.xy, tuple(self.offset_mm), self.drop_to_bed)  # type: ignore[arg-type]


class ToolpathJobParams(JobParams):
    slice_job_id: str = Field(description="a succeeded slice job; its layers.json is filled")
    pattern: Pattern = core_field(
        ToolpathParams, "pattern", description="raster (zigzag), lines (raster without links), contour (offsets), "
        "zone (partition scanning), hilbert (plain fractal), hilbert_merged (the published improved fractal: one "
        "circuit)")
    line_width_mm: float = core_field(ToolpathParams, "line_width_mm", allow_inf_nan=False,
                                      description="bead width, mm")
    nozzle_mm: float = core_field(ToolpathParams, "nozzle_mm", allow_inf_nan=False, description="nozzle diameter, mm")
    layer_height_mm: float | None = core_field(ToolpathParams, "layer_height_mm", allow_inf_nan=False,
                                               description="bead height for E; default each layer's thickness")
    infill: float = core_field(ToolpathParams, "infill", allow_inf_nan=False, description="infill density (0, 1]")
    perimeters: int = core_field(ToolpathParams, "perimeters", description="closed loops inside each ring")
    angle_deg: float = core_field(ToolpathParams, "angle_deg", allow_inf_nan=False, description="raster angle, deg",
                                  json_schema_extra=_MORE)
    angle_step_deg: float = core_field(ToolpathParams, "angle_step_deg", allow_inf_nan=False,
                                       description="raster angle change per layer, deg", json_schema_extra=_MORE)
    print_feed_mm_min: Speed = Field(_mm_min(_FILL.print_feed_mm_s), description="infill feed, mm/min")
    perimeter_feed_mm_min: Speed = Field(_mm_min(_FILL.perimeter_feed_mm_s), description="perimeter feed, mm/min",
                                         json_schema_extra=_MORE)
    travel_feed_mm_min: Speed = Field(_mm_min(_FILL.travel_feed_mm_s), description="travel feed, mm/min",
                                      json_schema_extra=_MORE)
    filament_mm: float = core_field(ToolpathParams, "filament_mm", allow_inf_nan=False,
                                    description="filament diameter, mm", json_schema_extra=_EXTRUDE_MORE)
    turn_threshold_deg: float = core_field(ToolpathParams, "turn_threshold_deg", allow_inf_nan=False,
                                           description="direction changes above this count as turns, deg",
                                           json_schema_extra=_MORE)
    resolution_mm: float = core_field(ToolpathParams, "resolution_mm", allow_inf_nan=False,
                                      description="the machine's resolution: paths are simplified to it and no move "
                                                  "is shorter, mm", json_schema_extra=_MORE)
    merge_weight_along: float = core_field(MergeWeights, "along", allow_inf_nan=False,
                                           description="hilbert_merged: weight of merging along the layer direction",
                                           json_schema_extra=_MERGED)
    merge_weight_across: float = core_field(MergeWeights, "across", allow_inf_nan=False,
                                            description="hilbert_merged: weight of merging across it",
                                            json_schema_extra=_MERGED)
    accel_mm_s2: float = core_field(MachineLimits, "accel_mm_s2", allow_inf_nan=False,
                                    description="printing acceleration (M204 P), mm/s^2", json_schema_extra=_MORE)
    travel_accel_mm_s2: float = core_field(MachineLimits, "travel_accel_mm_s2", allow_inf_nan=False,
                                           description="travel acceleration (M204 T)", json_schema_extra=_MORE)
    retract_accel_mm_s2: float = core_field(MachineLimits, "retract_accel_mm_s2", allow_inf_nan=False,
                                            description="retract acceleration (M204 R)",
                                            json_schema_extra=_EXTRUDE_MORE)
    junction_deviation_mm: float = core_field(MachineLimits, "junction_deviation_mm", allow_inf_nan=False,
                                              description="Marlin junction deviation (M205 J), mm",
                                              json_schema_extra=_MORE)
    max_feed_mm_s: tuple[Speed, Speed, Speed, Speed] = Field(_LIMITS.max_feed_mm_s,
                                                             description="axis feed limits X Y Z E (M203), mm/s",
                                                             json_schema_extra=_MORE)
    max_accel_mm_s2: tuple[Accel, Accel, Accel, Accel] = Field(_LIMITS.max_accel_mm_s2,
                                                               description="axis acceleration limits X Y Z E (M201)",
                                                               json_schema_extra=_MORE)
    dialect: DispensingDialect = Field(DEFAULT_DIALECT, description="G-code dialect (extrude needs marlin)")
    mode: FdmMode = core_field(FdmParams, "mode", description="E-axis extrusion or dispenser on/off")
    nozzle_temp_c: float = core_field(FdmParams, "nozzle_temp_c", allow_inf_nan=False, description="extrude, deg C",
                                      json_schema_extra=_EXTRUDE)
    bed_temp_c: float = core_field(FdmParams, "bed_temp_c", allow_inf_nan=False, description="extrude, deg C",
                                   json_schema_extra=_EXTRUDE)
    retract_mm: float = core_field(FdmParams, "retract_mm", allow_inf_nan=False, description="retraction length, mm",
                                   json_schema_extra=_EXTRUDE_MORE)
    retract_feed_mm_min: Speed = Field(_mm_min(_FDM.retract_feed_mm_s), description="retraction feed, mm/min",
                                       json_schema_extra=_EXTRUDE_MORE)
    z_lift_mm: float = core_field(FdmParams, "z_lift_mm", allow_inf_nan=False, description="lift during travel, mm",
                                  json_schema_extra=_MORE)
    min_travel_for_retract_mm: float = core_field(FdmParams, "min_travel_for_retract_mm", allow_inf_nan=False,
                                                  description="retract only before longer travels, mm",
                                                  json_schema_extra=_EXTRUDE_MORE)
    home: bool = core_field(FdmParams, "home", description="home (G28) in the start section", json_schema_extra=_MORE)
    dispense_on: Command | None = Field(None, description=f"dispense mode: on command (default: the dialect's, "
                                        f"{_DEFAULT_ON})",
                                        json_schema_extra=_DISPENSE_MORE)
    dispense_off: Command | None = Field(None, description=f"dispense mode: off command (default: the dialect's, "
                                         f"{_DEFAULT_OFF})",
                                         json_schema_extra=_DISPENSE_MORE)
    placement: PlacementIn = Field(default_factory=PlacementIn, description="where the part goes on the machine "
                                   "(default: dropped to the bed and centred)", json_schema_extra=_MORE)
    machine_id: str | None = Field(None, description="take the travel limits (profile.volume_mm) of this machine")
    volume_mm: VolumeIn | None = Field(None, description="the machine's travel limits, mm (default: the machine's "
                                       "profile, else a 200 x 200 x 200 mm machine with its origin at a bed corner)",
                                       json_schema_extra=_MORE)

    def limits(self) -> MachineLimits:
        return MachineLimits(**core_values(MachineLimits, self))

    def fill(self) -> ToolpathParams:
        """The planner's parameters: this job's by name, the feeds in mm/s from the job's mm/min."""
        return ToolpathParams(**core_values(
            ToolpathParams, self, print_feed_mm_s=self.print_feed_mm_min / MM_MIN_PER_MM_S,
            perimeter_feed_mm_s=self.perimeter_feed_mm_min / MM_MIN_PER_MM_S,
            travel_feed_mm_s=self.travel_feed_mm_min / MM_MIN_PER_MM_S, limits=self.limits(),
            merge_weights=MergeWeights(along=self.merge_weight_along, across=self.merge_weight_across)))

    def fdm(self, job_id: str | None) -> FdmParams:
        return FdmParams(**core_values(FdmParams, self, job_id=job_id,
                                       retract_feed_mm_s=self.retract_feed_mm_min / MM_MIN_PER_MM_S))


def _check(params: ToolpathJobParams, reads: JobReads) -> None:
    """The slice job must be a succeeded slice job; extrusion needs the marlin dialect."""
    job = reads.succeeded_job(params.slice_job_id, "slice", "params.slice_job_id", error=SlicingError,
                              hint=" (submit the toolpath once the slice has succeeded)")
    if params.mode == "extrude" and not GCODE_DIALECTS[params.dialect].extrusion:
        raise SlicingError("extrusion (E axis) output needs the marlin dialect; use mode: dispense on grbl",
                           field="params.dialect", value=params.dialect)
    params.fill().validate()
    machine = None
    if params.machine_id is not None and params.volume_mm is None:
        machine = reads.machine(params.machine_id, field="params.machine_id")
    volume = machine_volume(params, machine)
    bounds = SliceResult.of(job).bounds
    if bounds:
        placed = np.asarray(bounds, dtype=float) + placement_shift(np.asarray(bounds), params.placement.core(), volume)
        check_inside(placed + [[0, 0, 0], [0, 0, END_LIFT_MM + params.z_lift_mm]], volume,
                     what="the part (with the program's end lift), placed on the bed,")


def machine_volume(params: ToolpathJobParams, machine: Machine | None) -> MachineVolume:
    """The travel limits: the parameters', else the profile's of ``machine`` (the record of
    ``params.machine_id``), else the default bed."""
    if params.volume_mm is not None:
        return params.volume_mm.volume("params.volume_mm")
    if machine is not None:
        given = (machine.profile or {}).get("volume_mm")
        if given:
            return VolumeIn(**given).volume(f"machine {machine.id} profile.volume_mm")
        return dataclasses.replace(MachineVolume(), source=f"machine {machine.id} has no profile.volume_mm; "
                                   + MachineVolume().source)
    return MachineVolume()


def _per_layer(stats: list[tuple[int, float, float, LayerStats, int]], layer_times: tuple[float, ...]) -> list[dict]:
    """Per-layer rows from (index, z, thickness, stats, pieces) and the estimated layer times."""
    return [{"index": index, "z": z, "thickness": thickness, **_counts(st),
             "time_s": layer_times[index] if index < len(layer_times) else 0.0,
             "planner_time_s": st.time_s, "pieces": pieces}
            for index, z, thickness, st, pieces in stats]


def _counts(stats: LayerStats) -> dict[str, Any]:
    """The moves' counts of ``stats`` (:class:`PathCounts`' fields; its ``time_s`` is the planner's)."""
    return {f.name: getattr(stats, f.name) for f in dataclasses.fields(PathCounts)}


def _references(params: ToolpathJobParams) -> list[tuple[str, str]]:
    return [("job", params.slice_job_id)] + ([("machine", params.machine_id)] if params.machine_id else [])


# Cost model, calibrated on a 2-core machine (tests/bench/test_bench_compute_limits.py and
# tests/bench/test_bench_job_memory.py): the fractal fills build a grid of cells at the pitch
# line_width / infill over each layer's footprint; hilbert_merged peaked at ~440 bytes and
# 40-80 us per cell.  The other fills are planned and written a layer at a time, so what
# grows is the program, ~PROGRAM_LINE_BYTES per written line (its text and the compact rows
# the writer records for the time estimate and bounds) and ~LINE_S each, beside the slice's contours
# read from layers.npz (~SLICE_VERTEX_BYTES per vertex).  Lines are predicted from the
# slice: ~INFILL_LINES per sqrt(layer area) / pitch (scan lines at the angle, with their
# links) and ~CONTOUR_LINES per mm of contour per perimeter (simplified to the resolution,
# so a finer mesh of the same part writes the same lines).
CELL_BYTES = 500.0
CELL_S = 80e-6
PROGRAM_LINE_BYTES = 600.0
SLICE_VERTEX_BYTES = 30.0
LINE_S = 150e-6
INFILL_LINES = 6.7
CONTOUR_LINES = 0.5
GRID_BASE_MB = 100.0  # the fractal fills' numpy/scipy buffers on top of their cells


def predicted_lines(slice_result: SliceResult, pitch: float, perimeters: int) -> float:
    """Program lines a scan-line or contour fill of ``slice_result`` writes (see the cost model);
    a slice job without its contour length is counted at ~1 line per 2 vertices."""
    sqrt_area = sum(math.sqrt(max(float(row.get("area_mm2") or 0.0), 0.0)) for row in slice_result.layers)
    contour = slice_result.contour_mm
    contour_lines = CONTOUR_LINES * contour if contour is not None else 0.5 * (slice_result.vertices or 0)
    return INFILL_LINES * sqrt_area / pitch + contour_lines * max(1, perimeters)


def slice_vertices(slice_result: SliceResult, faces: int) -> int:
    """The slice's contour vertices (recorded, else ~8 sqrt(faces) per layer)."""
    if slice_result.vertices is not None:
        return slice_result.vertices
    return int(8 * math.sqrt(max(faces, 1)) * max(1, slice_result.layer_count))


def _estimate(params: ToolpathJobParams, reads: JobReads) -> Cost | None:
    """Predicted peak memory and time of the fill from the slice job's layers and the part's
    footprint; names params.line_width_mm (or params.infill when that is what shrinks the pitch)."""
    job = reads.find_job(params.slice_job_id)
    part = reads.find_part((job.params or {}).get("part_id")) if job is not None else None
    if job is None or part is None or job.kind != "slice" or job.status != "succeeded":
        return None
    (x0, y0, _), (x1, y1, _) = part.bounds
    pitch = params.line_width_mm / params.infill
    sliced = SliceResult.of(job)
    layers = max(1, sliced.layer_count)
    cols, rows = (x1 - x0) / pitch + 2, (y1 - y0) / pitch + 2
    if params.pattern in ("hilbert", "hilbert_merged"):
        cells = cols * rows
        memory_mb = GRID_BASE_MB + CELL_BYTES * cells / 2**20
        seconds = CELL_S * cells * layers
        basis = f"{cells:,.0f} fill cells per layer at pitch {pitch:g} mm, {layers} layers"
    else:
        lines = predicted_lines(sliced, pitch, params.perimeters)
        memory_mb = (PROGRAM_LINE_BYTES * lines + SLICE_VERTEX_BYTES * slice_vertices(sliced, part.faces)) / 2**20
        seconds = LINE_S * lines
        basis = f"about {lines:,.0f} program lines at pitch {pitch:g} mm, {layers} layers"
    field, value = (("params.infill", params.infill) if params.infill < 0.5
                    else ("params.line_width_mm", params.line_width_mm))
    return Cost(memory_mb=memory_mb, time_s=seconds, field=field, value=value, basis=basis)


def _layers(ctx: JobContext, slice_job_id: str) -> SlicedLayers:
    """The slice job's layers: its ``layers.npz`` (no text to parse), else (a slice job
    stored before it wrote one) its ``layers.json``; the same contours either way."""
    try:
        return from_binary(ctx.artifact_bytes(slice_job_id, BINARY_LAYERS))
    except ConformaError as exc:
        if exc.field != "artifact":
            raise
    return from_json(ctx.artifact_bytes(slice_job_id, "layers.json"))


@job_kind("toolpath", ToolpathJobParams, references=_references, check=_check, estimate=_estimate,
          heap_keep_bytes=HEAP_TOP_KEEP_BYTES)  # the writer churns blocks of a few hundred KiB
def run(ctx: JobContext, params: ToolpathJobParams) -> dict:
    """Fill the layers of a slice job (raster, contour, zone, Hilbert, S5 merged fractal) and write G-code."""
    ctx.require_succeeded(params.slice_job_id, "slice", "params.slice_job_id")
    sliced = _layers(ctx, params.slice_job_id)
    machine = (ctx.machine(params.machine_id) if params.machine_id is not None and params.volume_mm is None
               else None)
    volume = machine_volume(params, machine)
    shift = placement_shift(sliced.bounds, params.placement.core(), volume)
    sliced = translated(sliced, shift)
    ctx.progress(0.1, f"filling {len(sliced.layers)} layers ({params.pattern})")
    fill = params.fill()
    stats: list[tuple[int, float, float, LayerStats, int]] = []

    def planned() -> Iterator[LayerToolpath]:  # each layer written as it is planned, then let go
        for layer in iter_toolpath(sliced, fill):
            stats.append((layer.index, layer.z, layer.thickness, layer.stats, len(layer.pieces)))
            yield layer

    # the program's moves as read_program would read them from the text, kept as it is written
    gcode, program = write_fdm_program(planned(), fill, params.fdm(ctx.job_id))
    totals = totals_of(row[3] for row in stats)
    if totals.path_mm <= 0:
        raise SlicingError(f"the part yields no extrusion at line width {params.line_width_mm:g} mm: every section "
                           f"is thinner than {THINNEST_WALL:g} of the {params.nozzle_mm:g} mm nozzle",
                           field="params.line_width_mm", value=params.line_width_mm)
    ctx.progress(0.7, "estimating the print time")
    limits = params.limits()
    estimate = estimate_program(program, limits)
    meta = gcode_meta(gcode, program)
    del program
    if meta["bounds"] is not None:
        check_inside(np.asarray(meta["bounds"]), volume, what="print.gcode")
    ctx.artifact("print.gcode", gcode.encode(), "text/x-gcode", meta)
    return ToolpathResult.written({
        "time_s": estimate.total_s,
        "planner_time_s": totals.time_s,
        "estimator": {"name": "app.gcode.estimator.estimate_gcode (marlin-jd, full lookahead)",
                      "description": limits.describe(), "limits": dataclasses.asdict(limits)},
        "pattern": params.pattern,
        "layer_count": len(stats),
        **_counts(totals),
        "program": meta,
        "placement": {**params.placement.model_dump(), "shift_mm": [float(v) for v in shift],
                      "volume_mm": volume.describe(),
                      "note": f"the part's frame moved by {np.round(shift, 6).tolist()} mm into the machine's"},
        "layers": _per_layer(stats, estimate.layer_times),
    })
