"""Job ``jetting_run``: droplet layers jetted on a machine, closed by the height sensor.

Per layer: the pattern (open loop: the part mask; ``mpc``: the published layer-to-layer MPC
on the last measured map) goes to the print head swath by swath, the machine's UV-lamp
output cures it, the sensor rasters the grid (:mod:`app.jobs.jetting_machine`; on a
``linuxcnc://`` machine the controller samples the sensor with its joints, no
``sensor_port``; the lamp is a motion digital output, ``M64 P3`` / ``M65 P3``).  Heights are
measured from the substrate, scanned once before the first layer (``substrate.npz``).  Cells
the scan saw nothing in (dropouts: dark spots, lost light) take the controller's prediction
(:func:`app.jetting.machine_grid.fill_missing`).  Artifacts ``measured_NNNN.npz``: the layer's
``heights`` (L, W) float32 mm (as measured, NaN: no sample), ``filled`` (L, W) float32 mm
(what the controller used), ``pattern`` (L, W) bool, ``mask`` and ``pitch_mm``.

Rules as for a print: the operator's pause holds the streamed moves (the head fires on
position: each drop once); nothing dispenses unless the operator submitted or resumed the job;
a lost link (machine, head or sensor) interrupts it (``program_state``: layers printed and
measured, the phase), and only an operator's resume continues it: re-home, cure what may be
liquid, scan, and go on with the next layer (a layer cut short counts as printed: the
controller fills what it lacks; open loop does not).  Other failures end the job.
"""

from __future__ import annotations

import io
from typing import Any, Literal

import numpy as np
from pydantic import Field

from app.calibration.sensor import SensorCalibration
from app.domain.errors import Cancelled, InvalidInput
from app.jetting import drop_kernel, surface_metrics
from app.jetting.controller import mpc_layer
from app.jetting.flow import mobility_map
from app.jetting.machine_grid import Grid, fill_missing, predicted_heights, substrate_map
from app.jobs.jetting_inputs import (
    NPZ_MEDIA_TYPE,
    PrintModelParams,
    check_target,
    core_errors,
    target_of,
    target_references,
)
from app.jobs.jetting_machine import MachineSetup, cure, print_layer, scan_layer
from app.jobs.results.jetting import JettingRunResult
from app.jobs.sensor_runs import HalScanner, SerialScanner, open_scanner, require_sensor_port
from app.machines.live import MachineFault, MachineUnavailable, translate
from app.runtime.context import JobContext
from app.runtime.machine_queue import (
    interrupt,
    refuse_if_machine_busy,
    rehomed_machine,
    resume_request,
    stopped_by_operator,
)
from app.runtime.reads import JobReads
from app.runtime.registry import job_kind
from hardware.errors import HardwareError, LinkError
from hardware.printhead import PrintHead

SCAN_ABOVE_MM = 0.1  # the sensor's zero this far above the expected top (well inside its range)
COMMAND = r"^[^\n\r;]{1,80}$"


class JettingRunParams(PrintModelParams):
    machine_id: str
    head_port: str = Field(min_length=1, max_length=500,
                           description="the head driver's link: head://NAME (the mock), /dev/ttyUSB2, "
                                       "socket://host:port")
    sensor_port: str | None = Field(None, min_length=1, max_length=500, description=(
        "the height sensor's link: lkg://NAME (the mock), /dev/ttyUSB1, socket://host:port; not used on a "
        "linuxcnc:// machine (the controller samples the sensor with its joints)"))
    sensor_rate_hz: float = Field(2000.0, gt=0, le=100_000, description="the sensor's sampling rate (a "
                                  "linuxcnc:// machine samples once per servo period)")
    calibration: dict[str, Any] = Field(description="the sensor's calibration: offset_mm [x, y, z], scale, "
                                        "time_offset_s, slope_bias_mm (app.calibration.sensor.SensorCalibration)")
    layers: int = Field(200, ge=1, le=10_000, description="layers to print")
    controller: Literal["mpc", "open_loop"] = Field("mpc", description="open_loop: the part mask every layer; "
                                                    "mpc: the layer-to-layer MPC on the measured map")
    origin_mm: list[float] = Field(min_length=2, max_length=2, description="bed x, y of the grid's cell [0, 0] centre")
    head_offset_mm: list[float] = Field(min_length=2, max_length=2,
                                        description="nozzle 0 relative to the carriage, x, y")
    bed_z_mm: float = Field(0.0, ge=-500, le=500, description="the substrate's top under the grid")
    print_z_mm: float = Field(5.0, ge=-500, le=500, description="carriage z while jetting")
    travel_z_mm: float = Field(10.0, ge=-500, le=500, description="carriage z between passes")
    print_speed_mm_s: float = Field(100.0, gt=0, le=2000)
    scan_speed_mm_s: float = Field(100.0, gt=0, le=1000)
    cure_on: str = Field("M42 P6 S255", pattern=COMMAND, description="one command: the UV lamp on "
                         "(LinuxCNC: a motion digital output, M64 P3)")
    cure_off: str = Field("M42 P6 S0", pattern=COMMAND, description="one command: the UV lamp off "
                          "(LinuxCNC: M65 P3)")
    cure_s: float = Field(0.3, ge=0, le=600, description="UV exposure per layer, s")


def _check(params: JettingRunParams, reads: JobReads) -> None:
    try:
        SensorCalibration.from_dict(params.calibration)
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInput(f"calibration: {exc}", field="params.calibration", value=str(params.calibration)[:80]) \
            from None
    row = reads.machine(params.machine_id, field="params.machine_id")
    require_sensor_port(params.machine_id, row.port, params.sensor_port, "params.sensor_port")
    reads.notes["jetting_grid"] = check_target(params.target, params.core(), reads)
    refuse_if_machine_busy(params.machine_id, reads)


def _setup(params: JettingRunParams) -> MachineSetup:
    return MachineSetup((params.head_offset_mm[0], params.head_offset_mm[1]), params.print_z_mm, params.travel_z_mm,
                        params.print_speed_mm_s, params.scan_speed_mm_s, params.cure_on, params.cure_off,
                        params.cure_s, params.bed_z_mm)


def _npz(**arrays: Any) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


@job_kind("jetting_run", JettingRunParams, queue="machine", check=_check,
          references=lambda p: [("machine", p.machine_id), *target_references(p.target)])
def run(ctx: JobContext, params: JettingRunParams) -> dict:
    """Jet, cure and scan layer by layer (module docstring)."""
    core = params.core()
    target = target_of(params.target, core, lambda job_id, name: ctx.artifact_bytes(job_id, name))
    grid = Grid(target.shape, target.pitch_mm, (params.origin_mm[0], params.origin_mm[1]))
    calibration = SensorCalibration.from_dict(params.calibration)
    ctrl = params.controller_params(params.controller)
    kernel, step_mm = drop_kernel(core.drop), ctrl.fill * core.drop.layer_mm
    setup = _setup(params)
    resume = resume_request(ctx)
    state: dict[str, Any] = {"total": params.layers, "executed": 0, "printed": 0, "phase": "start", "layers": [],
                             "resumes": 0}
    state.update({k: resume[k] for k in ("executed", "printed", "phase", "layers", "resumes", "substrate", "pattern")
                  if resume and k in resume})
    machine = rehomed_machine(ctx, params.machine_id, resume, state)
    head = PrintHead(params.head_port)
    scanner: SerialScanner | HalScanner | None = None
    records: list[dict[str, Any]] = state["layers"]
    mobility = mobility_map(np.zeros(target.shape), core.flow)

    def top_mm() -> float:
        return SCAN_ABOVE_MM + (state["printed"] * core.drop.layer_mm)

    def measure(before: np.ndarray, pattern: np.ndarray | None) -> tuple[np.ndarray, dict[str, Any]]:
        state["phase"] = "scan"
        ctx.save_program_state(state)
        assert scanner is not None
        scan = scan_layer(machine, scanner, grid, calibration, setup, top_mm())
        heights = scan.heights - substrate
        predicted = before if pattern is None else predicted_heights(before, pattern, kernel, core.flow, ctrl.model)
        filled, missing = fill_missing(heights, predicted)
        return filled, {"raw": heights, "valid_fraction": scan.valid / max(scan.samples, 1),
                        "filled_cells": missing, "scans": scan.scans}

    def record(layer: int, filled: np.ndarray, scan: dict[str, Any], pattern: np.ndarray, fired: int,
               solve_ms: float) -> None:
        ctx.artifact(f"measured_{layer:04d}.npz", _npz(heights=scan["raw"].astype(np.float32),
                                                       filled=filled.astype(np.float32), pattern=pattern,
                                                       mask=target.mask, pitch_mm=np.float64(grid.pitch_mm)),
                     NPZ_MEDIA_TYPE, {"layer": layer, "shape": list(grid.shape)})
        metrics = surface_metrics(filled, target, layer * step_mm).as_dict()
        records.append({"layer": layer, **metrics, "drops": int(pattern.sum()), "fired": fired, "solve_ms": solve_ms,
                        **{k: scan[k] for k in ("valid_fraction", "filled_cells", "scans")}})
        state.update(executed=layer, phase="measured")
        ctx.save_program_state(state)
        ctx.progress(layer / params.layers, f"layer {layer}/{params.layers} measured")

    try:
        with ctx.lease(params.machine_id):
            head.connect()
            scanner = open_scanner(machine, params.sensor_port, params.sensor_rate_hz)
            if head.info is not None and abs(head.info.dpi - params.dpi) > 1e-6:
                raise InvalidInput(f"the head prints at {head.info.dpi:g} dpi, the job at {params.dpi:g}",
                                   field="params.dpi", value=params.dpi)
            substrate = _substrate(ctx, machine, scanner, grid, calibration, setup, state)
            measured = _last_measured(ctx, state, target.shape)
            pattern: np.ndarray | None = None
            warm: np.ndarray | None = None
            if resume is not None and state["phase"] != "start":  # cure what may be liquid, then look
                cure(machine, setup)
                measured, scan = measure(measured, None)
                if state["printed"] > state["executed"]:  # the layer the interruption cut short
                    cut = np.unpackbits(np.frombuffer(bytes.fromhex(state["pattern"]), dtype=np.uint8))
                    record(state["printed"], measured, scan, cut[:measured.size].reshape(target.shape).astype(bool),
                           -1, 0.0)
            for layer in range(state["printed"], params.layers):
                ctx.progress(layer / params.layers, f"layer {layer + 1}/{params.layers}: planning")
                solve_ms = 0.0
                if ctrl.kind == "mpc":
                    with core_errors():
                        decision = mpc_layer(measured, target, kernel, core.drop, core.flow, mobility, ctrl, layer,
                                             None if pattern is None else pattern.astype(float), warm)
                    pattern, solve_ms = decision.pattern, decision.solve_ms
                    warm = np.concatenate([decision.relaxed[1:], decision.relaxed[-1:]])  # as the simulation
                else:
                    pattern = target.mask
                state.update(printed=layer + 1, phase="print", pattern=np.packbits(pattern).tobytes().hex())
                ctx.save_program_state(state)
                printed = print_layer(machine, head, pattern, grid, setup)
                state["phase"] = "cure"
                cure(machine, setup)
                measured, scan = measure(measured, pattern)
                record(layer + 1, measured, scan, pattern, printed.fired, solve_ms)
            machine.move(z=setup.travel_z_mm)
    except HardwareError as exc:
        if isinstance(exc, LinkError) or stopped_by_operator(ctx, machine):
            raise interrupt(ctx, machine, exc, state) from exc
        raise translate(exc) from exc
    except (MachineUnavailable, MachineFault) as exc:
        raise interrupt(ctx, machine, exc, state) from exc
    except Cancelled:
        raise
    finally:
        head.close()
        if scanner is not None:
            scanner.close()
    solve = [r["solve_ms"] for r in records if r["solve_ms"] > 0]
    return JettingRunResult.written({
        "layers": records, "final": records[-1],
        "grid": {"shape": list(grid.shape), "pitch_mm": grid.pitch_mm, "part_cells": int(target.mask.sum()),
                 "layer_height_um": core.drop.layer_mm * 1e3},
        "controller": params.controller, "resumes": state["resumes"],
        "solve_ms_median": float(np.median(solve)) if solve else 0.0})


def _substrate(ctx: JobContext, machine: Any, scanner: SerialScanner | HalScanner, grid: Grid,
               calibration: SensorCalibration, setup: MachineSetup, state: dict[str, Any]) -> np.ndarray:
    """The substrate's heights (L, W) mm under the grid: scanned before the first layer
    (``substrate.npz``, smoothed: :func:`app.jetting.machine_grid.substrate_map`), read back on a
    resume."""
    if state.get("substrate"):
        with np.load(io.BytesIO(ctx.artifact_bytes(ctx.job_id, "substrate.npz"))) as data:
            return np.asarray(data["heights"], dtype=float)
    scan = scan_layer(machine, scanner, grid, calibration, setup, SCAN_ABOVE_MM)
    with core_errors():
        heights = substrate_map(scan.heights, grid.pitch_mm)
    ctx.artifact("substrate.npz", _npz(heights=heights.astype(np.float32), pitch_mm=np.float64(grid.pitch_mm)),
                 NPZ_MEDIA_TYPE, {"shape": list(grid.shape), "valid_fraction": scan.valid / max(scan.samples, 1)})
    state["substrate"] = True
    ctx.save_program_state(state)
    return heights


def _last_measured(ctx: JobContext, state: dict[str, Any], shape: tuple[int, int]) -> np.ndarray:
    """The filled map of the last measured layer (zeros before the first)."""
    if not state["executed"]:
        return np.zeros(shape)
    with np.load(io.BytesIO(ctx.artifact_bytes(ctx.job_id, f"measured_{state['executed']:04d}.npz"))) as data:
        return np.asarray(data["filled"], dtype=float)
