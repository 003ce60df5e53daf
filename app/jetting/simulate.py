"""Entry points: the simulated closed loop (``simulate``) and the printer-facing
``next_layer`` (measured height map in, next 0/1 pattern out)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .controller import LayerDecision, SolveFigures, mpc_layer, validate_controller
from .encode import npz_bytes
from .errors import JettingError
from .flow import mobility_map, substrate_tilt
from .kernel import drop_kernel
from .metrics import SurfaceMetrics, surface_metrics
from .params import JettingParams
from .plant import Plant
from .targets import Target, target_from_spec

WORK_ARRAYS_PER_CELL = 40  # float64 temporaries of one layer (flow, transport, QP, FISTA)


@dataclass(frozen=True)
class LayerSolve(SolveFigures):
    """A printed layer's own figures: its number, the drops printed and the controller's
    solve (:class:`~app.jetting.controller.SolveFigures`: ms, iterations, integer gap, KKT
    residual; 0 open loop)."""

    layer: int
    drops: int


@dataclass(frozen=True)
class LayerRecord(LayerSolve):
    """One printed layer: its figures (:class:`LayerSolve`) and its metrics (true heights)."""

    metrics: SurfaceMetrics

    def as_dict(self) -> dict[str, float | int]:
        out: dict[str, float | int] = {"layer": self.layer, **self.metrics.as_dict()}
        out.update(drops=self.drops, solve_ms=self.solve_ms, solve_cpu_ms=self.solve_cpu_ms,
                   iterations=self.iterations,
                   integer_gap=self.integer_gap, kkt_residual=self.kkt_residual)
        return out


@dataclass(frozen=True)
class SimulationResult:
    """layers: per-layer records; patterns: (n, L, W) bool printed patterns; heights:
    (k, L, W) float32 true height snapshots, mm, at ``snapshot_layers``; final_heights:
    (L, W) mm; target: the grid and part."""

    layers: tuple[LayerRecord, ...]
    patterns: npt.NDArray[np.bool_]
    heights: npt.NDArray[np.float32]
    snapshot_layers: tuple[int, ...]
    final_heights: npt.NDArray[np.float64]
    target: Target

    @property
    def final(self) -> LayerRecord:
        return self.layers[-1]

    def summary(self) -> dict[str, object]:
        """JSON-ready metric curves: {"layers": [per-layer dicts], "final": {...}}."""
        return {"layers": [r.as_dict() for r in self.layers], "final": self.final.as_dict()}

    def patterns_npz(self) -> bytes:
        """NPZ bytes: ``patterns`` (n, L, W) bool, ``mask`` (L, W), ``pitch_mm``."""
        return npz_bytes(patterns=self.patterns, mask=self.target.mask,
                         pitch_mm=np.float64(self.target.pitch_mm))

    def heights_npz(self) -> bytes:
        """NPZ bytes: ``heights`` (k, L, W) float32 mm, ``layers`` (k,), ``final`` (L, W) mm."""
        return npz_bytes(heights=self.heights, layers=np.asarray(self.snapshot_layers),
                         final=self.final_heights, pitch_mm=np.float64(self.target.pitch_mm))


def estimate_bytes(shape: tuple[int, int], params: JettingParams) -> int:
    """Memory a run needs: working arrays, packed patterns and float32 snapshots."""
    cells = int(shape[0]) * int(shape[1])
    per_layer = WORK_ARRAYS_PER_CELL + 4 * params.flow.flow_steps + 3 * params.controller.horizon
    snaps = 1 + (params.layers // params.snapshot_every if params.snapshot_every > 0 else 0)
    return cells * (8 * per_layer + params.layers + 4 * snaps)


def check_memory(shape: tuple[int, int], params: JettingParams) -> None:
    """Raise ``JettingError`` (field ``drop.dpi``) when a run would exceed the memory limit."""
    need = estimate_bytes(shape, params)
    if need > params.memory_limit_bytes:
        raise JettingError(
            f"a {shape[0]} x {shape[1]} grid at {params.drop.dpi} dpi needs "
            f"~{need / 2**20:.0f} MiB, "
            f"over the {params.memory_limit_bytes / 2**20:.0f} MiB limit",
            field="drop.dpi", value=params.drop.dpi)


def _validate(params: JettingParams) -> None:
    if not 1 <= params.layers <= 100_000:
        raise JettingError("layers must be in 1..100000", field="layers", value=params.layers)
    if params.flow.flow_steps < 0 or params.flow.threshold_um < 0 or not 0 <= params.flow.mobility <= 1:
        raise JettingError("invalid flow parameters", field="flow",
                           value=[params.flow.flow_steps, params.flow.threshold_um,
                                  params.flow.mobility])
    validate_controller(params.controller)


def simulate(params: JettingParams, target: Target | None = None,
             substrate_mm: npt.NDArray[np.float64] | None = None,
             progress: Callable[[int, int], None] | None = None) -> SimulationResult:
    """Print ``params.layers`` layers on the simulated plant, open loop or with the MPC.

    target: the part on its grid (default: ``params.target``, the seed's square with a
    hole); substrate_mm: optional (L, W) substrate height map (curved substrate: its
    tilt raises the flow mobility above lambda); progress(done, total) is called after
    each layer (it may raise to cancel). All validation happens before the first layer.
    """
    _validate(params)
    kernel = drop_kernel(params.drop)
    if target is None:
        target = target_from_spec(params.target, params.drop, params.margin_mm)
    check_memory(target.shape, params)
    if substrate_mm is not None and np.shape(substrate_mm) != target.shape:
        raise JettingError("substrate must match the target grid", field="substrate",
                           value=list(np.shape(substrate_mm)))
    ctrl, drop = params.controller, params.drop
    tilt = substrate_tilt(substrate_mm, target.shape, drop.pitch_mm)
    plant = Plant(target.shape, kernel, params.flow, params.plant, tilt)
    model_mobility = mobility_map(tilt, params.flow)
    fill = ctrl.fill if ctrl.kind == "mpc" else 1.0
    patterns = np.zeros((params.layers,) + target.shape, dtype=bool)
    snaps: list[npt.NDArray[np.float32]] = []
    snap_layers: list[int] = []
    records: list[LayerRecord] = []
    guess, warm = None, None
    for layer in range(params.layers):
        decision: LayerDecision | None = None
        if ctrl.kind == "mpc":
            measured = plant.measure()
            decision = mpc_layer(measured, target, kernel, drop, params.flow, model_mobility,
                                 ctrl, layer, guess, warm)
            pattern = decision.pattern
            guess = pattern.astype(float)
            warm = np.concatenate([decision.relaxed[1:], decision.relaxed[-1:]])
        else:
            pattern = target.mask
        patterns[layer] = pattern
        heights = plant.print_layer(pattern)
        done = layer + 1
        metrics = surface_metrics(heights, target, done * fill * drop.layer_mm)
        records.append(LayerRecord(
            layer=done, metrics=metrics, drops=int(pattern.sum()),
            solve_ms=decision.solve_ms if decision else 0.0,
            solve_cpu_ms=decision.solve_cpu_ms if decision else 0.0,
            iterations=decision.iterations if decision else 0,
            integer_gap=decision.integer_gap if decision else 0.0,
            kkt_residual=decision.kkt_residual if decision else 0.0))
        every = params.snapshot_every
        if every > 0 and done % every == 0 and done != params.layers:
            snaps.append(heights.astype(np.float32))
            snap_layers.append(done)
        if progress is not None:
            progress(done, params.layers)
    snaps.append(plant.heights.astype(np.float32))
    snap_layers.append(params.layers)
    return SimulationResult(layers=tuple(records), patterns=patterns, heights=np.stack(snaps),
                            snapshot_layers=tuple(snap_layers), final_heights=plant.heights.copy(),
                            target=target)


def next_layer(measured_height_mm: npt.NDArray[np.float64], target: Target, params: JettingParams,
               layer: int | None = None, previous_pattern: npt.NDArray[np.bool_] | None = None,
               substrate_mm: npt.NDArray[np.float64] | None = None) -> LayerDecision:
    """The next layer's 0/1 pattern for a real printer from a measured height map.

    measured_height_mm: (L, W) heights on the target's grid, mm (errors name it ``measured``); layer: layers printed so
    far (default: the measured mean part height in reference layers, rounded);
    previous_pattern: (L, W) last printed pattern (freezes the flow prediction; default
    ``fill`` everywhere on the part). Uses ``params.controller`` as an MPC.
    """
    validate_controller(params.controller)
    h = np.asarray(measured_height_mm, dtype=float)
    if h.shape != target.shape:
        raise JettingError("height map must match the target grid", field="measured",
                           value=[list(h.shape), list(target.shape)])
    if not np.isfinite(h).all():
        raise JettingError("height map has non-finite values", field="measured",
                           value=int((~np.isfinite(h)).sum()))
    check_memory(target.shape, params)
    kernel = drop_kernel(params.drop)
    step = params.controller.fill * params.drop.layer_mm
    if layer is None:
        layer = max(round(float(h[target.mask].mean()) / step), 0)
    if layer < 0:
        raise JettingError("layer must be >= 0", field="layer", value=layer)
    guess = None if previous_pattern is None else np.asarray(previous_pattern, dtype=float)
    if guess is not None and guess.shape != target.shape:
        raise JettingError("previous pattern must match the target grid",
                           field="previous_pattern", value=list(guess.shape))
    tilt = substrate_tilt(substrate_mm, target.shape, params.drop.pitch_mm)
    mobility = mobility_map(tilt, params.flow)
    return mpc_layer(h, target, kernel, params.drop, params.flow, mobility, params.controller,
                     layer, guess)
