"""Job ``jetting_next_layer``: a measured height map in, the next layer's drop pattern out.

The form a real jetting printer uses between layers (the jetting MPC, one receding-horizon
step).  The measured map comes inline (``measured.heights_um``, bounded size) or from a
stored NPZ artifact holding ``heights`` (k, L, W) mm and ``layers`` (k,) - the
``heights.npz`` of a ``jetting`` job (pick the snapshot with ``measured.layer``).
Artifacts: ``next_pattern.png`` (1 bit, one pixel per print cell, white = drop) and
``next_pattern.npz`` (``pattern`` (L, W) bool, ``relaxed`` (m, L, W) QP optimum in drops,
``reference_mm`` (L, W), ``mask`` (L, W) bool, ``pitch_mm``).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Annotated

import numpy as np
from pydantic import Field, model_validator

from app.jetting import (
    JettingError,
    QpFigures,
    next_layer,
    npz_arrays,
    npz_bytes,
    pattern_png,
    png_pattern,
)
from app.jobs.jetting_inputs import (
    NPZ_MEDIA_TYPE,
    PrintModelParams,
    StrictModel,
    check_target,
    core_errors,
    npz_meta,
    stored_artifact,
    target_of,
    target_references,
)
from app.jobs.results.jetting import NextLayerResult
from app.platform.array_files import load_npz
from app.runtime.context import JobContext
from app.runtime.reads import JobReads
from app.runtime.registry import job_kind

MAX_INLINE_CELLS_PER_AXIS = 512
HEIGHTS_NPZ = "heights.npz"
UM_PER_MM = 1e3

Finite = Annotated[float, Field(allow_inf_nan=False, ge=-1e6, le=1e6)]
Row = Annotated[list[Finite], Field(min_length=1, max_length=MAX_INLINE_CELLS_PER_AXIS)]


class MeasuredSource(StrictModel):
    """The measured height map on the target's grid: inline, or a stored NPZ artifact."""

    heights_um: list[Row] | None = Field(
        None, min_length=1, max_length=MAX_INLINE_CELLS_PER_AXIS,
        description="inline (L, W) heights, um, on the target's print grid (row i, column j = pixel "
        "(i, j) of the pattern PNGs; the grid is the target's bounding box plus the margin)")
    job_id: str | None = Field(None, description="a succeeded job with a heights NPZ (a jetting job)")
    file_id: str | None = Field(None, description="an uploaded NPZ (POST /api/v1/files) from the printer's "
                                "height sensor: array heights (L, W) mm, or heights (k, L, W) with layers (k,)")
    artifact: str | None = Field(None, min_length=1, max_length=200, description="that job's NPZ with "
                                 f"arrays heights (k, L, W) mm and layers (k,) (default {HEIGHTS_NPZ})")
    layer: int | None = Field(None, ge=0, le=1_000_000,
                              description="the snapshot to use: a value of the NPZ's layers array (default: the last)")

    @model_validator(mode="after")
    def _one_source(self) -> MeasuredSource:
        if sum(v is not None for v in (self.heights_um, self.job_id, self.file_id)) != 1:
            raise ValueError("give exactly one of heights_um, job_id or file_id")
        if self.file_id is not None and self.artifact is not None:
            raise ValueError("artifact selects a job's NPZ; not with file_id")
        if self.heights_um is not None:
            if self.layer is not None or self.artifact is not None:
                raise ValueError("layer and artifact select a stored NPZ; not with heights_um")
            if len({len(row) for row in self.heights_um}) != 1:
                raise ValueError("heights_um rows must all have the same length")
        return self

    @property
    def npz_name(self) -> str:
        return self.artifact or HEIGHTS_NPZ


class PatternRef(StrictModel):
    job_id: str = Field(description="a succeeded job holding the PNG")
    artifact: str = Field(min_length=1, max_length=200, description="e.g. pattern_0020.png or next_pattern.png")


class NextLayerParams(PrintModelParams):
    measured: MeasuredSource = Field(description="the measured height map (inline or a stored NPZ)")
    layer: int | None = Field(None, ge=0, le=1_000_000, description="layers printed so far (default: the "
                              "measured mean part height over fill x the nominal layer height, rounded)")
    previous_pattern: PatternRef | None = Field(
        None, description="the last printed pattern (1-bit PNG): the flow prediction is frozen at it "
        "(default: fill on every part cell)")


def _references(params: NextLayerParams) -> list[tuple[str, str]]:  # uploaded files are not deletable records
    refs = target_references(params.target)
    refs += [("job", params.measured.job_id)] if params.measured.job_id else []
    refs += [("job", params.previous_pattern.job_id)] if params.previous_pattern else []
    return refs


def _mismatch(field: str, got: list[int], grid: tuple[int, int]) -> JettingError:
    return JettingError(f"{field}: a {got[0]} x {got[1]} map does not match the target's {grid[0]} x {grid[1]} "
                        "print grid (same target, dpi, drop and margin as the print)", field=field, value=got)


def _check(params: NextLayerParams, reads: JobReads) -> None:
    """The target, the grid sizes of the measured map and previous pattern, the snapshot layer."""
    grid = check_target(params.target, params.core(), reads)
    measured = params.measured
    if measured.heights_um is not None:
        got = [len(measured.heights_um), len(measured.heights_um[0])]
        if grid is not None and tuple(got) != grid:
            raise _mismatch("params.measured.heights_um", got, grid)
    elif measured.file_id is not None:
        upload = reads.find_upload(measured.file_id)
        if upload is None or upload.media_type != NPZ_MEDIA_TYPE:
            state = "does not exist" if upload is None else f"is {upload.media_type}"
            raise JettingError(f"params.measured.file_id: file {measured.file_id!r} {state}; an NPZ is needed",
                               field="params.measured.file_id", value=measured.file_id)
    else:
        row = stored_artifact(reads, measured.job_id or "", measured.npz_name, "params.measured", NPZ_MEDIA_TYPE)
        shape = row.meta.get("arrays", {}).get("heights")
        if shape is None:
            raise JettingError("params.measured: the artifact holds no heights array",
                               field="params.measured", value=measured.npz_name)
        if grid is not None and tuple(shape[1:]) != grid:
            raise _mismatch("params.measured", shape[1:], grid)
        if measured.layer is not None and measured.layer not in row.meta.get("layers", []):
            raise JettingError(f"params.measured.layer: no snapshot after layer {measured.layer}; "
                               f"the NPZ holds {row.meta.get('layers')}", field="params.measured.layer",
                               value=measured.layer)
    if params.previous_pattern is not None:
        ref = params.previous_pattern
        row = stored_artifact(reads, ref.job_id, ref.artifact, "params.previous_pattern", "image/png")
        shape = row.meta.get("shape")
        if grid is not None and shape is not None and tuple(shape) != grid:
            raise _mismatch("params.previous_pattern", shape, grid)


def measured_heights_mm(ctx: JobContext, measured: MeasuredSource) -> tuple[np.ndarray, int | None]:
    """(L, W) measured heights, mm, and the snapshot's layer (None for inline maps)."""
    if measured.heights_um is not None:
        return np.asarray(measured.heights_um, dtype=float) / UM_PER_MM, None
    if measured.file_id is not None:
        # an upload: inflated under a hard cap, whatever its zip directory says
        arrays = load_npz(ctx.file_bytes(measured.file_id, field="params.measured.file_id"),
                          ctx.max_upload_bytes, field="params.measured.file_id")
        if arrays.get("heights") is not None and arrays["heights"].ndim == 2:
            return np.asarray(arrays["heights"], dtype=float), None
    else:
        arrays = npz_arrays(ctx.artifact_bytes(measured.job_id or "", measured.npz_name))
    heights, layers = arrays.get("heights"), arrays.get("layers")
    if heights is None or layers is None or heights.ndim != 3 or layers.shape != (len(heights),):
        raise JettingError("params.measured: the NPZ needs heights (k, L, W) and layers (k,)",
                           field="params.measured", value=sorted(arrays))
    index = len(layers) - 1 if measured.layer is None else int(np.flatnonzero(layers == measured.layer)[0])
    return np.asarray(heights[index], dtype=float), int(layers[index])


@job_kind("jetting_next_layer", NextLayerParams, references=_references, check=_check)
def run(ctx: JobContext, params: NextLayerParams) -> dict:
    """The next layer's 0/1 drop pattern from a measured height map (one MPC step)."""
    core = params.core()
    target = target_of(params.target, core, lambda job_id, name: ctx.artifact_bytes(job_id, name))
    heights_mm, snapshot = measured_heights_mm(ctx, params.measured)
    if heights_mm.shape != target.shape:
        raise _mismatch("params.measured", list(heights_mm.shape), target.shape)
    previous = None
    if params.previous_pattern is not None:
        previous = png_pattern(ctx.artifact_bytes(params.previous_pattern.job_id, params.previous_pattern.artifact))
    ctx.progress(0.2, f"solving the layer QP on {target.shape[0]} x {target.shape[1]} cells")
    with core_errors():
        decision = next_layer(heights_mm, target, core, params.layer, previous)
    ctx.progress(0.9, "writing the pattern")
    grid = list(target.shape)
    drops = int(decision.pattern.sum())
    ctx.artifact("next_pattern.png", pattern_png(decision.pattern, params.dpi), "image/png",
                 {"drops": drops, "shape": grid, "dpi": params.dpi})
    ctx.artifact("next_pattern.npz",
                 npz_bytes(pattern=decision.pattern, relaxed=decision.relaxed, reference_mm=decision.reference_mm,
                           mask=target.mask, pitch_mm=np.float64(target.pitch_mm)),
                 NPZ_MEDIA_TYPE, npz_meta(pattern=grid, relaxed=list(decision.relaxed.shape), reference_mm=grid,
                                          mask=grid, pitch_mm=[]))
    return NextLayerResult.written({
        **{f.name: getattr(decision, f.name) for f in fields(QpFigures)},
        "drops": drops,
        "reference_height_um": float(decision.level_mm * UM_PER_MM),
        "measured_layer": snapshot,
        "grid": {"shape": grid, "pitch_mm": target.pitch_mm, "part_cells": int(target.mask.sum()),
                 "layer_height_um": core.drop.layer_mm * UM_PER_MM},
    })
