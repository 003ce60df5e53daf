"""Job ``slice``: a part into layers of closed rings (the multi-cavity slicing rules), with SLC/CLI/JSON/SVG exports.

Beam (track-width) compensation is chosen by ``beam``: ``none``; ``seed_haz`` - the seed
S4 heat-affected widths (21 / 23 / 24 / 25.5 / 28 um at 20 / 25 / 30 / 35 / 40 um layers,
interpolated linearly in each layer's thickness, end values outside); ``table`` - the
caller's own ``beam_table``; or a constant inward ``offset_mm`` (with ``beam: none``).
Compensated contours are what every artifact carries (the SLC table's compensation
entry is then 0).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from app.jobs.core_fields import core_field, core_values
from app.jobs.form_hints import form
from app.jobs.results.models import SliceResult
from app.platform.models import Part
from app.runtime.context import JobContext
from app.runtime.cost import Cost
from app.runtime.heap import HEAP_TOP_KEEP_BYTES
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind
from app.slicing import SEED_HAZ_TABLE, BeamWidthTable, SliceParams, SlicingError, compensate_beam, slice_mesh
from app.slicing.adaptive import uniform_plan
from app.slicing.export import SlcOptions, layer_svg, to_cli, to_json, to_slc
from app.slicing.export_binary import NAME as BINARY_LAYERS
from app.slicing.export_binary import to_binary
from app.slicing.layers import Remainder, SeedSample, SliceMode, ThetaRule
from app.slicing.layers import SliceResult as SlicedLayers
from app.slicing.mesh_prep import default_max_hole_mm
from app.slicing.rings import per_array, ring_length

MAX_LAYERS = 100_000  # a slice job never makes more layers than this (422 at submission)
_CORE = SliceParams()
_SLC = SlcOptions()
ARTIFACT_BATCH_BYTES = 16 * 2**20  # the exports wait for one commit together up to this many bytes

# form hints (app.jobs.form_hints): folded fields, and the fields of one mode or beam only
_MORE = form(advanced=True)
_ADAPTIVE = form(unit="mm", when={"mode": ["area", "cavity", "cusp"]})
_TABLE = form(advanced=True, when={"beam": ["table"]})
_OFFSET = form(advanced=True, when={"beam": ["none"]})
Thickness = Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)]
Width = Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)]


class BeamTable(BaseModel):
    """Compensation width per layer thickness (ascending thicknesses, one width each)."""

    model_config = ConfigDict(extra="forbid")
    thickness_mm: list[Thickness] = Field(min_length=1, max_length=64, description="layer thicknesses, mm, ascending")
    width_mm: list[Width] = Field(min_length=1, max_length=64,
                                  description="inward contour offset at each thickness, mm")

    @model_validator(mode="after")
    def _ascending_pairs(self) -> BeamTable:
        if len(self.thickness_mm) != len(self.width_mm):
            raise ValueError("beam_table needs one width_mm per thickness_mm")
        if any(b <= a for a, b in zip(self.thickness_mm, self.thickness_mm[1:])):
            raise ValueError("beam_table.thickness_mm must be strictly ascending")
        return self


class SliceJobParams(JobParams):
    part_id: str = Field(description="the part to slice")
    mode: SliceMode = core_field(
        SliceParams, "mode", description="uniform: layers of layer_mm, the remainder distributed or merged (see "
        "remainder); area: the published area-deviation rule (eps0, l_min, l_max); cavity: the multi-cavity "
        "refinement (adds sigma0, mu0, mu1); cusp: our cusp-height rule (cusp_mm, l_min, l_max)")
    layer_mm: float = core_field(SliceParams, "layer_mm", allow_inf_nan=False, description="uniform layer "
                                 "thickness, mm", title="Layer thickness",
                                 json_schema_extra=form(unit="mm", when={"mode": ["uniform"]}))
    l_min: float = core_field(SliceParams, "l_min", allow_inf_nan=False, description="thinnest adaptive layer, mm",
                              title="Thinnest layer", json_schema_extra=_ADAPTIVE)
    l_max: float = core_field(SliceParams, "l_max", allow_inf_nan=False, description="thickest adaptive layer, mm",
                              title="Thickest layer", json_schema_extra=_ADAPTIVE)
    eps0: float = core_field(SliceParams, "eps0", allow_inf_nan=False,
                             description="allowed relative area change between layers (S4)",
                             title="Allowed area change ε0", json_schema_extra=form(when={"mode": ["area", "cavity"]}))
    sigma0: float = core_field(SliceParams, "sigma0", allow_inf_nan=False,
                               description="S4 inner-area ratio threshold sum(A_in)/A_out",
                               title="Inner-area ratio threshold σ0", json_schema_extra=form(when={"mode": ["cavity"]}))
    mu0: float = core_field(SliceParams, "mu0", allow_inf_nan=False, description="S4 lower mean inner ratio",
                            title="Lower mean inner ratio μ0", json_schema_extra=form(when={"mode": ["cavity"]}))
    mu1: float = core_field(SliceParams, "mu1", allow_inf_nan=False, description="S4 upper mean inner ratio",
                            title="Upper mean inner ratio μ1", json_schema_extra=form(when={"mode": ["cavity"]}))
    theta_rule: ThetaRule = core_field(
        SliceParams, "theta_rule", description="S4 theta: indicator (sigma >= sigma0, the seed's text) or the "
        "printed formula", title="θ rule", json_schema_extra=form(advanced=True, when={"mode": ["cavity"]}))
    step9_resets_to_lmax: bool = core_field(
        SliceParams, "step9_resets_to_lmax", description="read S4 step 9 literally (non-cavity layers always l_max)",
        title="Step 9 resets to the thickest layer", json_schema_extra=form(advanced=True, when={"mode": ["cavity"]}))
    seed_sample: SeedSample = core_field(
        SliceParams, "seed_sample", description="area/cavity modes: contour at mid-height (default, inside the "
        "layer) or at the layer top (as published)", title="Contour sampled at",
        json_schema_extra=form(advanced=True, when={"mode": ["area", "cavity"]}))
    remainder: Remainder = core_field(
        SliceParams, "remainder", description="uniform mode, a height that is not a multiple of layer_mm: "
        "distribute (round(H / layer_mm) equal layers) or merge (layer_mm layers; a remainder under half a layer "
        "joins the last one). Never a sliver.", json_schema_extra=form(when={"mode": ["uniform"]}))
    cusp_mm: float = core_field(SliceParams, "cusp_mm", allow_inf_nan=False,
                                description="allowed cusp height (cusp mode), mm", title="Allowed cusp height",
                                json_schema_extra=form(when={"mode": ["cusp"]}))
    repair: bool = core_field(SliceParams, "repair", description="repair a bad mesh (reported) instead of refusing "
                              "it: winding and normals fixed, holes filled, shells united", title="Repair a bad mesh")
    max_hole_mm: float | None = core_field(
        SliceParams, "max_hole_mm", allow_inf_nan=False, description="repair fills holes up to this perimeter, mm "
        "(default: the perimeter of the part's bounding box's largest face); larger holes are refused with their "
        "size", title="Largest hole repaired", json_schema_extra=_MORE)
    beam: Literal["none", "seed_haz", "table"] = Field(
        "none", description="beam compensation: none, seed_haz (the published heat-affected widths 21-28 um for "
        "20-40 um layers, linear in thickness) or table (beam_table)", title="Beam compensation",
        json_schema_extra=_MORE)
    beam_table: BeamTable | None = Field(None, description="own compensation table (beam: table)",
                                         title="Beam compensation table", json_schema_extra=_TABLE)
    offset_mm: float | None = Field(None, ge=0, le=10, allow_inf_nan=False,
                                    description="constant inward contour offset, mm (with beam: none)",
                                    title="Inward contour offset", json_schema_extra=_OFFSET)
    slc_quantum_mm: float = Field(_SLC.quantum_mm, gt=0, le=1, allow_inf_nan=False,
                                  description="SLC thickness grid: adaptive thicknesses are rounded to it",
                                  title="SLC thickness grid", json_schema_extra=_MORE)
    svg_layer: int | None = Field(None, ge=0, description="layer drawn in layer.svg (default: the middle one)",
                                  title="Layer drawn in layer.svg", json_schema_extra=_MORE)

    def core(self) -> SliceParams:
        """The pure core's parameters."""
        return SliceParams(**core_values(SliceParams, self, {"z_tol"}, max_layers=MAX_LAYERS))

    def beam_compensation(self) -> BeamWidthTable | float | None:
        """What :func:`compensate_beam` gets (None: no compensation)."""
        if self.beam == "seed_haz":
            return SEED_HAZ_TABLE
        if self.beam == "table" and self.beam_table is not None:
            return BeamWidthTable(tuple(self.beam_table.thickness_mm), tuple(self.beam_table.width_mm))
        return self.offset_mm


def _most_layers(height_mm: float, params: SliceJobParams) -> int:
    """An upper bound of the layer count: every layer but the last is >= the thinnest step."""
    thinnest = params.layer_mm if params.mode == "uniform" else params.l_min
    return max(1, math.ceil(height_mm / thinnest - 1e-9))


def _thinnest_layer(height_mm: float, params: SliceJobParams) -> float:
    """A lower bound of the thinnest layer the planners make (no slivers, see
    :func:`app.slicing.adaptive.uniform_plan` and the adaptive planners' top merge)."""
    if params.mode == "uniform":
        plan = uniform_plan(height_mm, params.layer_mm, params.remainder, _CORE.z_tol)
        return min(plan)
    return min(height_mm, 0.5 * params.l_min)


def _check_repairable(part: Part, params: SliceJobParams) -> None:
    """An open mesh that repair cannot close is refused now, not after queuing (from the
    defects found at upload)."""
    defects = part.defects or {}
    if part.watertight or not params.repair or not defects:
        return
    if defects.get("non_manifold_edges"):
        raise SlicingError(f"the part's mesh cannot be made watertight: {defects['non_manifold_edges']} edges are "
                           f"shared by more than two faces", field="params.part_id", value=part.id)
    if not defects.get("closable", True):
        raise SlicingError("the part's mesh cannot be made watertight: an open boundary does not close into a "
                           "loop", field="params.part_id", value=part.id)
    largest = defects.get("largest_hole_mm")
    limit = params.max_hole_mm if params.max_hole_mm is not None else default_max_hole_mm(np.asarray(part.bounds))
    if largest is not None and largest > limit:
        raise SlicingError(f"the part's mesh cannot be made watertight: its largest hole is {largest:.4g} mm around, "
                           f"more than max_hole_mm = {limit:.4g} mm; close it in CAD or raise max_hole_mm",
                           field="params.max_hole_mm", value=params.max_hole_mm)


def _check(params: SliceJobParams, reads: JobReads) -> None:
    """Cross-field rules and the part's height and watertightness, before anything is queued."""
    params.core().validate()  # names params.l_min, params.mu0 ... (SlicingError, 422)
    if params.offset_mm is not None and params.beam != "none":
        raise SlicingError(f"offset_mm is a constant beam offset; it cannot be combined with beam={params.beam!r}",
                           field="params.offset_mm", value=params.offset_mm)
    if (params.beam == "table") != (params.beam_table is not None):
        raise SlicingError("beam_table is required with beam: table and only then",
                           field="params.beam_table", value=params.beam)
    part = reads.part(params.part_id, field="params.part_id")
    if not part.watertight and not params.repair:
        raise SlicingError("the part's mesh is not watertight; slice it with repair: true or upload a closed mesh",
                           field="params.repair", value=False)
    _check_repairable(part, params)
    height = float(part.bounds[1][2]) - float(part.bounds[0][2])
    most = _most_layers(height, params)
    if most > MAX_LAYERS:
        step = "params.layer_mm" if params.mode == "uniform" else "params.l_min"
        raise SlicingError(f"a {height:.6g} mm tall part could need {most} layers; at most {MAX_LAYERS} "
                           f"(use thicker layers)", field=step, value=getattr(params, step.split(".")[1]))
    thinnest = _thinnest_layer(height, params)
    if thinnest < params.slc_quantum_mm:
        step = "params.layer_mm" if params.mode == "uniform" else "params.l_min"
        raise SlicingError(f"layers down to {thinnest:.6g} mm would vanish on the SLC thickness quantum "
                           f"{params.slc_quantum_mm} mm; use thicker layers or a finer slc_quantum_mm",
                           field=step, value=getattr(params, step.split(".")[1]))
    if params.svg_layer is not None and params.svg_layer >= most:
        raise SlicingError(f"svg_layer {params.svg_layer} does not exist: this part gets at most {most} layers",
                           field="params.svg_layer", value=params.svg_layer)


def _layer_row(layer, beam_offset_mm: float | None) -> dict:
    row = {"index": layer.index, "z": layer.z_top, "z_bottom": layer.z_bottom, "z_sample": layer.z_sample,
           "thickness": layer.thickness, "area_mm2": layer.area, "rings": layer.ring_count,
           "inner_rings": layer.inner_ring_count, "sigma": layer.sigma, "mu": layer.mu, "eps": layer.eps,
           "reason": layer.reason}
    if beam_offset_mm is not None:
        row["beam_offset_mm"] = beam_offset_mm
    return row


# Cost model, calibrated against measured peaks (tests/bench/test_bench_job_memory.py): the
# mesh ~FACE_BYTES per face (trimesh's arrays and caches, the vectorised slicer's edge arrays),
# the contours ~VERTEX_BYTES per vertex (~VERTICES_PER_ROOT_FACE sqrt(faces) per layer) with
# their SLC / CLI / JSON text and the layers.npz arrays.  Adaptive modes are counted at their
# thinnest layer (the worst case).
FACE_BYTES = 560.0
VERTEX_BYTES = 75.0
VERTICES_PER_ROOT_FACE = 10.0
LAYER_S = 2e-3
BASE_MB = 8.0


def _estimate(params: SliceJobParams, reads: JobReads) -> Cost | None:
    """Predicted memory and time from the part's height and faces and the layer thickness;
    names params.layer_mm (uniform) or params.l_min (adaptive)."""
    part = reads.find_part(params.part_id)
    if part is None:
        return None
    height = float(part.bounds[1][2] - part.bounds[0][2])
    field, thickness = (("params.layer_mm", params.layer_mm) if params.mode == "uniform"
                        else ("params.l_min", params.l_min))
    layers = math.ceil(max(height, 0.0) / thickness) + 1
    vertices = VERTICES_PER_ROOT_FACE * math.sqrt(max(part.faces, 1))
    memory = BASE_MB + (FACE_BYTES * part.faces + VERTEX_BYTES * vertices * layers) / 2**20
    return Cost(memory_mb=memory, time_s=LAYER_S * layers * (1 + vertices / 1000), field=field, value=thickness,
                basis=f"{layers:,} layers of ~{vertices:,.0f} contour vertices, {part.faces:,} faces")


def _contour_mm(sliced: SlicedLayers) -> float:
    """The length of every layer's rings, mm (a ring array the layers of a prismatic band share
    measured once)."""
    length = per_array(ring_length)
    return float(sum(length(ring) for layer in sliced.layers for island in layer.islands
                     for ring in island.rings()))


@job_kind("slice", SliceJobParams, references=lambda p: [("part", p.part_id)], check=_check, estimate=_estimate,
          heap_keep_bytes=HEAP_TOP_KEEP_BYTES)  # its exports churn blocks of a few hundred KiB
def run(ctx: JobContext, params: SliceJobParams) -> dict:
    """Slice a part into layers (uniform, S4 area / multi-cavity adaptive, or cusp) and export them."""
    mesh = ctx.mesh(params.part_id)
    ctx.progress(0.05, f"slicing {len(mesh.faces)} faces ({params.mode})")
    sliced = slice_mesh(mesh, params.core())
    beam = params.beam_compensation()
    widths: list[float | None] = [None] * len(sliced.layers)
    if beam is not None:
        ctx.progress(0.5, f"beam compensation of {len(sliced.layers)} layers")
        sliced = compensate_beam(sliced, beam)
        table = beam if isinstance(beam, BeamWidthTable) else BeamWidthTable((1.0,), (float(beam),))
        widths = [table.width(layer.thickness) for layer in sliced.layers]
    ctx.progress(0.7, "writing SLC, CLI, JSON and SVG")
    slc = to_slc(sliced, SlcOptions(quantum_mm=params.slc_quantum_mm))
    notes = list(sliced.notes) + list(slc.notes)
    svg_index = len(sliced.layers) // 2 if params.svg_layer is None else params.svg_layer
    if svg_index >= len(sliced.layers):
        notes.append(f"svg_layer {svg_index} is beyond the {len(sliced.layers)} layers; layer.svg shows the last one")
        svg_index = len(sliced.layers) - 1
    chosen = sliced.layers[svg_index]
    count = {"layers": len(sliced.layers)}
    # the small files in one commit; a large one is stored (and let go) before the next is made
    with ctx.artifact_batch(ARTIFACT_BATCH_BYTES) as batch:
        batch.add("layers.slc", slc.data, "application/octet-stream",
                  {**count, "sampling_table_entries": len(slc.table)})
        batch.add("layers.cli", to_cli(sliced).encode(), "text/plain", count)
        batch.add("layers.json", to_json(sliced).encode(), "application/json", count)
        batch.add("layer.svg", layer_svg(sliced, svg_index).encode(), "image/svg+xml",
                  {"layer": svg_index, "z": chosen.z_top})
        batch.add(BINARY_LAYERS, to_binary(sliced), "application/octet-stream",
                  {**count, "note": "layers.json's content as arrays (what the toolpath job reads)"})
    return SliceResult.written({
        "mode": params.mode,
        "layer_count": len(sliced.layers),
        "vertices": int(sum(len(ring) for layer in sliced.layers for island in layer.islands
                            for ring in island.rings())),
        "contour_mm": _contour_mm(sliced),
        "z_min": sliced.z_min,
        "z_max": sliced.z_max,
        "bounds": [[float(v) for v in row] for row in sliced.bounds],
        "frame": "the part's own (toolpath places it on the machine)",
        "volume_mm3": sliced.volume,
        "repairs": list(sliced.repairs),
        "notes": notes,
        "beam": {"kind": "offset_mm" if params.beam == "none" and beam is not None else params.beam,
                 "offset_mm": params.offset_mm},
        "slc": {"quantum_mm": params.slc_quantum_mm, "sampling_table": [list(row) for row in slc.table]},
        "svg": {"layer": svg_index, "z": chosen.z_top, "artifact": "layer.svg"},
        "layers": [_layer_row(layer, w) for layer, w in zip(sliced.layers, widths)],
    })
