"""Job ``jetting``: the simulated droplet-jetting closed loop of seed S2 (open loop or MPC).

Thin adapter over :mod:`app.jetting`: the target (the seed's square with a
square hole, a 1-bit PNG mask, or one layer of a slice job) and every model, plant and
controller knob are validated at submission, including the grid's memory need, so bad
input is a 422 naming ``params.<field>`` before anything is queued.  Artifacts:
``patterns.npz`` (``patterns`` (n, L, W) bool, ``mask`` (L, W) bool, ``pitch_mm``),
``heights.npz`` (``heights`` (k, L, W) float32 mm, ``layers`` (k,), ``final`` (L, W) mm,
``pitch_mm``) and ``pattern_0001.png`` ... (1 bit, one pixel per print cell, white = drop).
The shared parameter and target models here are reused by ``jetting_next_layer``.
"""

from __future__ import annotations

import base64
import binascii
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from sqlmodel import Session

from app.jetting import (
    ControllerParams,
    DropParams,
    FlowParams,
    JettingError,
    JettingParams,
    PlantParams,
    Target,
    TargetSpec,
    estimate_bytes,
    pattern_png,
    simulate,
    target_from_png,
    target_from_rings,
    target_from_spec,
)
from app.jobs.context import JobContext
from app.jobs.cost import Cost
from app.jobs.registry import JobParams, job_kind
from app.models import Artifact, Job, Part
from app.slicing import SlicingError
from app.slicing.export import from_json

MEMORY_LIMIT_BYTES = 2 * 1024**3  # one run's working set (patterns, snapshots, solver temporaries)
MAX_PNG_ARTIFACTS = 1000          # per-layer pattern PNGs one job may write
MAX_MASK_BASE64 = 4_000_000       # inline mask PNG, base64 characters
NPZ_MEDIA_TYPE = "application/zip"  # an NPZ is a zip of .npy members (numpy.load reads it)
_CORE_FIELDS = {  # core error fields -> the API's parameter names
    "drop.dpi": "params.dpi", "drop.drop_diameter_um": "params.drop_diameter_um",
    "target.mask": "params.target.mask", "target.rings": "params.target.slice",
    "target.shape": "params.target.shape", "target.hole_mm": "params.target.hole_mm",
    "controller.kind": "params.controller", "measured_height": "params.measured",
    "layers.json": "params.target.slice",
}
_D, _F, _C, _P, _T = DropParams(), FlowParams(), ControllerParams(), PlantParams(), TargetSpec()


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid")


class MaskSource(StrictModel):
    """A part mask image: one pixel per print cell at ``dpi``, luminance >= 128 is part."""

    job_id: str | None = Field(None, description="a succeeded job holding the PNG as an artifact")
    artifact: str | None = Field(None, min_length=1, max_length=200,
                                 description="that job's artifact name, e.g. pattern_0001.png")
    png_base64: str | None = Field(None, max_length=MAX_MASK_BASE64,
                                   description="or the PNG itself, base64 (no data: prefix)")

    @model_validator(mode="after")
    def _one_source(self) -> MaskSource:
        if (self.job_id is None) != (self.artifact is None) or (self.job_id is None) == (self.png_base64 is None):
            raise ValueError("give either job_id and artifact, or png_base64")
        return self


class SliceSource(StrictModel):
    """One layer of a slice job's ``layers.json`` (its contours; holes are inner rings)."""

    slice_job_id: str = Field(description="a succeeded slice job")
    layer: int = Field(0, ge=0, le=1_000_000, description="layer index in that job's layers")


class TargetParams(StrictModel):
    """The part to print: the seed's parametric square with a centred square hole
    (default), or a mask image, or a slice layer (give at most one of mask / slice)."""

    shape: Literal["square_with_hole"] | None = Field(None, description="parametric shape (the default)")
    size_mm: float | None = Field(None, gt=0, le=500, allow_inf_nan=False,
                                  description=f"square side, mm (default {_T.size_mm:g})")
    hole_mm: float | None = Field(None, ge=0, le=500, allow_inf_nan=False,
                                  description=f"hole side, mm (default {_T.hole_mm:g}; 0: no hole)")
    mask: MaskSource | None = Field(None, description="part mask image instead of the square")
    slice: SliceSource | None = Field(None, description="slice layer instead of the square")

    @model_validator(mode="after")
    def _one_kind(self) -> TargetParams:
        parametric = [name for name in ("shape", "size_mm", "hole_mm") if getattr(self, name) is not None]
        if self.mask is not None and self.slice is not None:
            raise ValueError("give mask or slice, not both")
        if (self.mask is not None or self.slice is not None) and parametric:
            raise ValueError(f"{parametric} describe the parametric square; not with mask or slice")
        spec = self.spec()
        if spec.hole_mm >= spec.size_mm:
            raise ValueError("hole_mm must be smaller than size_mm")
        return self

    def spec(self) -> TargetSpec:
        """The parametric square with the defaults filled in."""
        return TargetSpec(shape=self.shape or _T.shape, size_mm=_T.size_mm if self.size_mm is None else self.size_mm,
                          hole_mm=_T.hole_mm if self.hole_mm is None else self.hole_mm)


class PrintModelParams(JobParams):
    """The print grid, droplet, threshold flow and MPC settings (shared by both jetting kinds)."""

    target: TargetParams = Field(default_factory=TargetParams, description="the part to print")
    dpi: float = Field(_D.dpi, ge=25, le=2400, allow_inf_nan=False, description="print resolution, dots per inch")
    drop_diameter_um: float = Field(_D.drop_diameter_um, gt=0, le=2000, allow_inf_nan=False,
                                    description="spread (landed) droplet diameter, um")
    drop_volume_pl: float = Field(_D.drop_volume_pl, gt=0, le=10_000, allow_inf_nan=False,
                                  description="nominal droplet volume, pL")
    margin_mm: float = Field(0.25, ge=0, le=10, allow_inf_nan=False, description="empty border around the part, mm")
    threshold_um: float = Field(_F.threshold_um, ge=0, le=1000, allow_inf_nan=False,
                                description="seed eq. 7: ink flows between neighbours only above this step, um")
    mobility: float = Field(_F.mobility, ge=0, le=1, allow_inf_nan=False,
                            description="flow mobility (2/pi) eta_s on a flat substrate, 0..1")
    flow_steps: int = Field(_F.steps, ge=0, le=50, description="flow sub-steps per layer before cure")
    horizon: int = Field(_C.horizon, ge=1, le=10, description="MPC horizon m, layers")
    q_weight: float = Field(_C.q_weight, ge=0, le=1e6, allow_inf_nan=False, description="MPC stage weight Q")
    r_weight: float = Field(_C.r_weight, ge=0, le=1e6, allow_inf_nan=False, description="MPC input weight R")
    f_weight: float = Field(_C.f_weight, gt=0, le=1e6, allow_inf_nan=False, description="MPC terminal weight F")
    outside_weight: float = Field(_C.outside_weight, ge=0, le=1e6, allow_inf_nan=False,
                                  description="weight of cells off the part relative to part cells")
    fill: float = Field(_C.fill, gt=0, le=1, allow_inf_nan=False,
                        description="MPC reference rise per layer in nominal layer heights")
    model: Literal["transport", "seed_diagonal"] = Field(
        _C.model, description="seed_diagonal: the seed's (I + Dg) B; transport: mass-conserving flow operator")
    solver: Literal["fista", "lbfgsb"] = Field(_C.solver, description="fista (fast) or lbfgsb (reference)")
    binarize: Literal["greedy", "threshold", "error_diffusion"] = Field(
        _C.binarize, description="relaxed -> 0/1 drops: greedy flips on the model's QP, threshold, error diffusion")
    max_iter: int = Field(_C.max_iter, ge=1, le=100_000, description="solver iteration cap per layer")
    tol: float = Field(_C.tol, gt=0, le=1, allow_inf_nan=False, description="solver tolerance (relative)")
    greedy_rounds: int = Field(_C.greedy_rounds, ge=0, le=50, description="greedy flip sweeps")

    def drop(self) -> DropParams:
        return DropParams(dpi=self.dpi, drop_diameter_um=self.drop_diameter_um, drop_volume_pl=self.drop_volume_pl)

    def flow(self) -> FlowParams:
        return FlowParams(threshold_um=self.threshold_um, mobility=self.mobility, steps=self.flow_steps)

    def controller_params(self, kind: str = "mpc") -> ControllerParams:
        return ControllerParams(kind=kind, horizon=self.horizon, q_weight=self.q_weight, r_weight=self.r_weight,
                                f_weight=self.f_weight, outside_weight=self.outside_weight, fill=self.fill,
                                model=self.model, solver=self.solver, binarize=self.binarize,
                                max_iter=self.max_iter, tol=self.tol, greedy_rounds=self.greedy_rounds)

    def core(self) -> JettingParams:
        """The pure core's parameters (``layers`` 1: the next-layer kind plans one layer)."""
        return JettingParams(drop=self.drop(), flow=self.flow(), controller=self.controller_params(),
                             target=self.target_spec(), layers=1, margin_mm=self.margin_mm,
                             memory_limit_bytes=MEMORY_LIMIT_BYTES)

    def target_spec(self) -> TargetSpec:
        return self.target.spec()


class JettingJobParams(PrintModelParams):
    layers: int = Field(200, ge=1, le=10_000, description="layers to print")
    controller: Literal["mpc", "open_loop"] = Field(
        "mpc", description="open_loop: the part mask every layer; mpc: the seed's layer-to-layer MPC")
    nozzle_spread: float = Field(_P.nozzle_spread, ge=0, le=0.5, allow_inf_nan=False,
                                 description="plant: per-nozzle volume spread (relative std)")
    drop_noise: float = Field(_P.drop_noise, ge=0, le=0.5, allow_inf_nan=False,
                              description="plant: per-drop volume noise (relative std)")
    volume_bias: float = Field(_P.volume_bias, ge=0.1, le=10, allow_inf_nan=False,
                               description="plant: true mean drop volume / nominal (model mismatch)")
    mobility_factor: float = Field(_P.mobility_factor, ge=0, le=10, allow_inf_nan=False,
                                   description="plant: true flow mobility / model's (clipped to 1)")
    threshold_factor: float = Field(_P.threshold_factor, ge=0, le=10, allow_inf_nan=False,
                                    description="plant: true flow threshold / model's")
    n_nozzles: int = Field(_P.n_nozzles, ge=1, le=100_000, description="plant: nozzles; column j uses j % n_nozzles")
    dead_nozzles: list[int] = Field(default_factory=list, max_length=1000,
                                    description="plant: indices of nozzles that never fire")
    sensor_noise_um: float = Field(_P.sensor_noise_um, ge=0, le=100, allow_inf_nan=False,
                                   description="plant: height-sensor noise (std), um")
    seed: int = Field(_P.seed, ge=0, le=2**32 - 1, description="plant random seed (same seed, same run)")
    png_every: int = Field(1, ge=0, le=10_000, description="write pattern_NNNN.png every k layers (0: none)")
    snapshot_every: int = Field(0, ge=0, le=10_000, description="keep a height map every k layers in "
                                "heights.npz (0: the final one only)")

    @model_validator(mode="after")
    def _bounded_outputs(self) -> JettingJobParams:
        if any(not 0 <= n < self.n_nozzles for n in self.dead_nozzles):
            raise ValueError(f"dead_nozzles must be in 0..{self.n_nozzles - 1}")
        if self.png_every and self.layers // self.png_every > MAX_PNG_ARTIFACTS:
            raise ValueError(f"{self.layers // self.png_every} pattern PNGs; at most {MAX_PNG_ARTIFACTS} "
                             "(raise png_every)")
        return self

    def core(self) -> JettingParams:
        plant = PlantParams(nozzle_spread=self.nozzle_spread, drop_noise=self.drop_noise,
                            volume_bias=self.volume_bias, mobility_factor=self.mobility_factor,
                            threshold_factor=self.threshold_factor, dead_nozzles=tuple(self.dead_nozzles),
                            n_nozzles=self.n_nozzles, sensor_noise_um=self.sensor_noise_um, seed=self.seed)
        return JettingParams(drop=self.drop(), flow=self.flow(), plant=plant,
                             controller=self.controller_params(self.controller), target=self.target_spec(),
                             layers=self.layers, margin_mm=self.margin_mm, snapshot_every=self.snapshot_every,
                             memory_limit_bytes=MEMORY_LIMIT_BYTES)


# errors and limits ---------------------------------------------------------------------
def api_field(field: str | None) -> str:
    """The API parameter a core error field names (``drop.dpi`` -> ``params.dpi``)."""
    if not field:
        return "params"
    if field.startswith("params"):
        return field
    if field in _CORE_FIELDS:
        return _CORE_FIELDS[field]
    head, _, rest = field.partition(".")
    return f"params.{rest}" if rest and head in ("drop", "flow", "plant", "controller") else f"params.{field}"


@contextmanager
def core_errors() -> Iterator[None]:
    """Re-raise the core's JettingError / SlicingError naming the API parameter."""
    try:
        yield
    except (JettingError, SlicingError) as exc:
        field = api_field(exc.field)
        message = exc.message if exc.message.startswith(field) else f"{field}: {exc.message}"
        raise JettingError(message, field=field, value=exc.value) from None


def max_cells(core: JettingParams) -> int:
    """The largest grid the memory limit allows (checked before a grid is allocated)."""
    return max(1, core.memory_limit_bytes // estimate_bytes((1, 1), core))


def check_grid(shape: tuple[int, int], core: JettingParams) -> None:
    """422 naming ``params.dpi`` when a grid of ``shape`` needs more than the memory limit."""
    need = estimate_bytes(shape, core)
    if need > core.memory_limit_bytes:
        raise JettingError(f"params.dpi: a {shape[0]} x {shape[1]} grid at {core.drop.dpi:g} dpi for "
                           f"{core.layers} layers needs ~{need / 2**20:.0f} MiB, over the "
                           f"{core.memory_limit_bytes / 2**20:.0f} MiB limit", field="params.dpi",
                           value=core.drop.dpi)


def _mask_bytes(source: MaskSource) -> bytes:
    try:
        return base64.b64decode(source.png_base64 or "", validate=True)
    except (binascii.Error, ValueError) as exc:
        raise JettingError(f"params.target.mask.png_base64: not base64 ({exc})",
                           field="params.target.mask.png_base64", value=len(source.png_base64 or "")) from None


# targets ---------------------------------------------------------------------------------
ArtifactReader = Callable[[str, str], bytes]  # (job_id, artifact name) -> bytes


def target_of(spec: TargetParams, core: JettingParams, read: ArtifactReader) -> Target:
    """The print target on its grid; ``read(job_id, name)`` returns an artifact's bytes."""
    limit = max_cells(core)
    with core_errors():
        if spec.mask is not None:
            data = _mask_bytes(spec.mask) if spec.mask.png_base64 is not None else \
                read(spec.mask.job_id or "", spec.mask.artifact or "")
            target = target_from_png(data, core.drop, core.margin_mm, limit)
        elif spec.slice is not None:
            layers = from_json(read(spec.slice.slice_job_id, "layers.json")).layers
            if spec.slice.layer >= len(layers):
                raise JettingError(f"layer {spec.slice.layer} does not exist ({len(layers)} layers)",
                                   field="params.target.slice.layer", value=spec.slice.layer)
            rings = [ring for island in layers[spec.slice.layer].islands for ring in island.rings()]
            target = target_from_rings(rings, core.drop, core.margin_mm, limit)
        else:
            target = target_from_spec(core.target, core.drop, core.margin_mm, limit)
    check_grid(target.shape, core)
    return target


def _succeeded_job(session: Session, job_id: str, field: str, kind: str | None = None) -> Job:
    job = session.get(Job, job_id)
    if job is None or job.status != "succeeded" or (kind is not None and job.kind != kind):
        state = "does not exist" if job is None else f"is a {job.status} {job.kind} job"
        needed = f"a succeeded {kind} job" if kind else "a succeeded job"
        raise JettingError(f"{field}: job {job_id!r} {state}; {needed} is needed", field=field, value=job_id)
    return job


def stored_artifact(session: Session, job_id: str, name: str, field: str, media_type: str) -> Artifact:
    """The artifact row of a succeeded job with the expected media type, or a 422 naming ``field``."""
    _succeeded_job(session, job_id, field)
    row = session.query(Artifact).filter(Artifact.job_id == job_id, Artifact.name == name).one_or_none()
    if row is None or row.media_type != media_type or row.bytes == 0:
        what = "does not exist" if row is None else f"is an empty or {row.media_type} file"
        raise JettingError(f"{field}: artifact {name!r} of job {job_id!r} {what}; a {media_type} is needed",
                           field=field, value=name)
    return row


def check_target(spec: TargetParams, core: JettingParams, session: Session) -> tuple[int, int] | None:
    """Submission-time checks of the target: the grid's memory need, the mask artifact's
    type and part cells, the slice layer's existence and the sliced part's extent; when the
    session can read stored files (as it can at submission), the target is built and fully
    validated now.  Returns the grid shape when it is known."""
    reader = _stored_reader(session)
    if spec.mask is not None and spec.mask.job_id is not None:
        row = stored_artifact(session, spec.mask.job_id, spec.mask.artifact or "", "params.target.mask", "image/png")
        if row.meta.get("drops") == 0:
            raise JettingError("params.target.mask: the mask image is all black (no part cells)",
                               field="params.target.mask", value=spec.mask.artifact)
        if "shape" in row.meta:
            drop = core.drop
            pad = 2 * (math.ceil(core.margin_mm / drop.pitch_mm) + math.ceil(drop.radius_mm / drop.pitch_mm) + 3)
            check_grid((int(row.meta["shape"][0]) + pad, int(row.meta["shape"][1]) + pad), core)
        return target_of(spec, core, reader).shape if reader is not None else None
    if spec.slice is not None:
        job = _succeeded_job(session, spec.slice.slice_job_id, "params.target.slice.slice_job_id", "slice")
        count = int((job.result or {}).get("layer_count", 0))
        if spec.slice.layer >= count:
            raise JettingError(f"params.target.slice.layer: layer {spec.slice.layer} does not exist "
                               f"({count} layers)", field="params.target.slice.layer", value=spec.slice.layer)
        part = session.get(Part, job.params.get("part_id", ""))
        if part is not None:
            extent = np.ptp(np.asarray(part.bounds, dtype=float)[:, :2], axis=0) + 2 * core.margin_mm
            cells = [math.ceil(e / core.drop.pitch_mm) + 1 for e in extent]
            check_grid((cells[0], cells[1]), core)
        return target_of(spec, core, reader).shape if reader is not None else None
    return target_of(spec, core, _no_reader).shape  # parametric or inline mask: built now


def _stored_reader(session: Session) -> ArtifactReader | None:
    """Reads a stored artifact's bytes during a submission check (the runtime puts a blob
    reader in ``session.info``), so stored masks and slices are fully checked up front."""
    read_blob = session.info.get("read_blob")
    if read_blob is None:
        return None

    def read(job_id: str, name: str) -> bytes:
        row = session.query(Artifact).filter(Artifact.job_id == job_id, Artifact.name == name).one()
        return read_blob(row.sha256)

    return read


def _no_reader(job_id: str, name: str) -> bytes:  # parametric and inline targets read no artifacts
    raise AssertionError(f"unexpected read of {job_id}/{name}")


def target_references(spec: TargetParams) -> list[tuple[str, str]]:
    if spec.mask is not None and spec.mask.job_id is not None:
        return [("job", spec.mask.job_id)]
    if spec.slice is not None:
        return [("job", spec.slice.slice_job_id)]
    return []


# the job -------------------------------------------------------------------------------
def _check(params: JettingJobParams, session: Session) -> None:
    session.info["jetting_grid"] = check_target(params.target, params.core(), session)


# Time model: a layer costs ~CELL_LAYER_S per cell and horizon step (FISTA solve, flow sub-steps,
# greedy flips; FIELD_NOTES: 118 x 118, m = 1 in 5-7 ms); memory is the core's estimate_bytes.
CELL_LAYER_S = 2e-6


def _estimate(params: JettingJobParams, session: Session) -> Cost | None:
    """Predicted memory (the core's own estimate) and time of the run; names params.dpi
    (or params.layers when the layer count is what makes it long)."""
    shape = session.info.get("jetting_grid")
    if shape is None:
        return None
    core = params.core()
    cells = int(shape[0]) * int(shape[1])
    seconds = CELL_LAYER_S * cells * params.layers * params.horizon * (1 + params.flow_steps / 10)
    field, value = ("params.layers", params.layers) if params.layers > 1000 else ("params.dpi", params.dpi)
    return Cost(memory_mb=estimate_bytes(tuple(shape), core) / 2**20, time_s=seconds, field=field, value=value,
                basis=f"a {shape[0]} x {shape[1]} grid for {params.layers} layers")


def npz_meta(**shapes: object) -> dict:
    return {"format": "npz", "arrays": shapes}


@job_kind("jetting", JettingJobParams, references=lambda p: target_references(p.target), check=_check,
          estimate=_estimate)
def run(ctx: JobContext, params: JettingJobParams) -> dict:
    """Simulate droplet jetting layer by layer (open loop or the seed's MPC) and measure the surface."""
    core = params.core()
    ctx.progress(0.01, "building the target")
    target = target_of(params.target, core, lambda job_id, name: ctx.artifact_bytes(job_id, name))
    ctx.progress(0.02, f"{target.shape[0]} x {target.shape[1]} cells, {int(target.mask.sum())} on the part")

    def report(done: int, total: int) -> None:
        ctx.progress(0.02 + 0.88 * done / total, f"layer {done}/{total}")

    with core_errors():
        result = simulate(core, target, progress=report)
    ctx.progress(0.9, "writing artifacts")
    grid = list(target.shape)
    ctx.artifact("patterns.npz", result.patterns_npz(), NPZ_MEDIA_TYPE,
                 npz_meta(patterns=list(result.patterns.shape), mask=grid, pitch_mm=[]))
    ctx.artifact("heights.npz", result.heights_npz(), NPZ_MEDIA_TYPE,
                 {**npz_meta(heights=list(result.heights.shape), layers=[len(result.snapshot_layers)],
                             final=grid, pitch_mm=[]), "layers": list(result.snapshot_layers)})
    names: list[str] = []
    for layer in range(params.png_every, params.layers + 1, params.png_every) if params.png_every else ():
        if len(names) % 50 == 49:
            ctx.progress(0.9 + 0.1 * layer / params.layers, f"pattern PNG of layer {layer}")
        pattern = result.patterns[layer - 1]
        names.append(f"pattern_{layer:04d}.png")
        ctx.artifact(names[-1], pattern_png(pattern, params.dpi), "image/png",
                     {"layer": layer, "drops": int(pattern.sum()), "shape": grid, "dpi": params.dpi})
    summary = result.summary()
    solve_ms = [row["solve_ms"] for row in summary["layers"]]  # type: ignore[union-attr]
    return {
        **summary,
        "grid": {"shape": grid, "pitch_mm": target.pitch_mm, "part_cells": int(target.mask.sum()),
                 "layer_height_um": core.drop.layer_mm * 1e3},
        "controller": params.controller,
        "solve_ms_median": float(np.median(solve_ms)),
        "pattern_pngs": names,
    }
