"""Job ``jetting``: the simulated droplet-jetting closed loop (open loop or the published MPC).

Thin adapter over :mod:`app.jetting`: the target (the seed's square with a
square hole, a 1-bit PNG mask, or one layer of a slice job) and every model, plant and
controller knob are validated at submission, including the grid's memory need, so bad
input is a 422 naming ``params.<field>`` before anything is queued.  Artifacts:
``patterns.npz`` (``patterns`` (n, L, W) bool, ``mask`` (L, W) bool, ``pitch_mm``),
``heights.npz`` (``heights`` (k, L, W) float32 mm, ``layers`` (k,), ``final`` (L, W) mm,
``pitch_mm``) and ``pattern_0001.png`` ... (1 bit, one pixel per print cell, white = drop).
The parameter and target models it shares with ``jetting_next_layer`` are in
:mod:`app.jobs.jetting_inputs`.
"""

from __future__ import annotations

from typing import Any, Literal, cast

import numpy as np
from pydantic import Field, model_validator

from app.jetting import JettingParams, PlantParams, estimate_bytes, pattern_png, simulate
from app.jobs.core_fields import core_field
from app.jobs.jetting_inputs import (
    MEMORY_LIMIT_BYTES,
    NPZ_MEDIA_TYPE,
    PrintModelParams,
    check_target,
    core_errors,
    npz_meta,
    target_of,
    target_references,
)
from app.jobs.results.jetting import JettingResult
from app.runtime.context import JobContext
from app.runtime.cost import Cost
from app.runtime.reads import JobReads
from app.runtime.registry import job_kind

MAX_PNG_ARTIFACTS = 1000          # per-layer pattern PNGs one job may write


class JettingJobParams(PrintModelParams):
    layers: int = Field(200, ge=1, le=10_000, description="layers to print")
    controller: Literal["mpc", "open_loop"] = Field(
        "mpc", description="open_loop: the part mask every layer; mpc: the seed's layer-to-layer MPC")
    nozzle_spread: float = core_field(PlantParams, "nozzle_spread", allow_inf_nan=False,
                                      description="plant: per-nozzle volume spread (relative std)")
    drop_noise: float = core_field(PlantParams, "drop_noise", allow_inf_nan=False,
                                   description="plant: per-drop volume noise (relative std)")
    volume_bias: float = core_field(PlantParams, "volume_bias", allow_inf_nan=False,
                                    description="plant: true mean drop volume / nominal (model mismatch)")
    mobility_factor: float = core_field(PlantParams, "mobility_factor", allow_inf_nan=False,
                                        description="plant: true flow mobility / model's (clipped to 1)")
    threshold_factor: float = core_field(PlantParams, "threshold_factor", allow_inf_nan=False,
                                         description="plant: true flow threshold / model's")
    n_nozzles: int = core_field(PlantParams, "n_nozzles", description="plant: nozzles; column j uses j % n_nozzles")
    dead_nozzles: list[int] = Field(default_factory=list, max_length=1000,
                                    description="plant: indices of nozzles that never fire")
    sensor_noise_um: float = core_field(PlantParams, "sensor_noise_um", allow_inf_nan=False,
                                        description="plant: height-sensor noise (std), um")
    seed: int = core_field(PlantParams, "seed", description="plant random seed (same seed, same run)")
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
        plant = PlantParams(**self.named(PlantParams))
        return JettingParams(drop=self.drop(), flow=self.flow(), plant=plant,
                             controller=self.controller_params(self.controller), target=self.target_spec(),
                             layers=self.layers, margin_mm=self.margin_mm, snapshot_every=self.snapshot_every,
                             memory_limit_bytes=MEMORY_LIMIT_BYTES)


# the job -------------------------------------------------------------------------------
def _check(params: JettingJobParams, reads: JobReads) -> None:
    reads.notes["jetting_grid"] = check_target(params.target, params.core(), reads)


# Time model: a layer costs ~CELL_LAYER_S per cell and horizon step (FISTA solve, flow sub-steps,
# greedy flips; FIELD_NOTES: 118 x 118, m = 1 in 5-7 ms); memory is the core's estimate_bytes.
CELL_LAYER_S = 2e-6


def _estimate(params: JettingJobParams, reads: JobReads) -> Cost | None:
    """Predicted memory (the core's own estimate) and time of the run; names params.dpi
    (or params.layers when the layer count is what makes it long)."""
    shape = reads.notes.get("jetting_grid")
    if shape is None:
        return None
    core = params.core()
    cells = int(shape[0]) * int(shape[1])
    seconds = CELL_LAYER_S * cells * params.layers * params.horizon * (1 + params.flow_steps / 10)
    field, value = ("params.layers", params.layers) if params.layers > 1000 else ("params.dpi", params.dpi)
    return Cost(memory_mb=estimate_bytes(tuple(shape), core) / 2**20, time_s=seconds, field=field, value=value,
                basis=f"a {shape[0]} x {shape[1]} grid for {params.layers} layers")


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
    solve_ms = [row["solve_ms"] for row in cast(list[dict[str, Any]], summary["layers"])]
    return JettingResult.written({
        **summary,
        "grid": {"shape": grid, "pitch_mm": target.pitch_mm, "part_cells": int(target.mask.sum()),
                 "layer_height_um": core.drop.layer_mm * 1e3},
        "controller": params.controller,
        "solve_ms_median": float(np.median(solve_ms)),
        "pattern_pngs": names,
    })
