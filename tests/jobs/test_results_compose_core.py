"""Result models that compose the core's dataclasses instead of copying their fields: the result's
fields are the core's (declared once there), and a core value written as a result and stored as
JSON reads back equal."""

from __future__ import annotations

import json
import typing
from dataclasses import MISSING, asdict, fields

import numpy as np
import trimesh
from pydantic import TypeAdapter

from app.calibration import NozzleCalibration, PretravelModel, ProbeCalibration
from app.calibration.sensor import SensorCalibration
from app.circuits.heightfield import HeightField
from app.circuits.warp import WarpFigures, WarpOptions, warp_program
from app.five_axis import FiveAxisParams, plan_five_axis
from app.five_axis.planner import FiveAxisFigures
from app.five_axis.trace import trace_over_xy
from app.jetting import JettingParams, LayerSolve, QpFigures, SurfaceMetrics, TargetSpec, next_layer, target_from_spec
from app.jobs.results.calibration import CalibrateNozzleResult, CalibrateProbeResult, CalibrateSensorResult
from app.jobs.results.five_axis import FiveAxisResult
from app.jobs.results.jetting import JettingLayer, NextLayerResult
from app.jobs.results.program import ToolpathLayer, ToolpathResult, WarpProgramResult
from app.slicing import SliceParams, slice_mesh
from app.slicing.toolpath import PathCounts, plan_toolpath
from tests.five_axis.conftest import sphere_cap

# the keys a stored five_axis result has always had (clients read them flat, at the top level)
FIVE_AXIS_KEYS = {
    "normal_source", "lines", "servo_periods", "duration_s", "max_normal_error_deg", "max_standoff_error_mm",
    "max_midpoint_error_mm", "nominal_max_normal_error_deg", "nominal_max_standoff_error_mm",
    "feed_fluctuation_pct", "feed_fluctuation_rms_pct", "feed_fluctuation_first_order_pct",
    "feed_fluctuation_first_order_rms_pct", "max_c_step_deg", "max_a_step_deg", "max_c_speed_deg_s",
    "max_a_speed_deg_s", "pole_lines", "split_lines", "split_rounds", "a_range_deg", "max_trace_deviation_mm",
    "dispense_on", "dispense_off", "post", "feed_fluctuation", "feed_fluctuation_first_order", "standoff_mm",
    "feed_mm_min", "feed_mode", "pivot", "surface_source", "surface", "offset_curve", "program",
    "nominal_program"}
FIVE_AXIS_JOB_KEYS = {"dispense_on": "M8", "dispense_off": "M9", "post": "conforma", "standoff_mm": 0.5,
                      "feed_mm_min": 1200.0, "feed_mode": "inverse_time", "pivot": [5.0, -3.0, -20.0],
                      "surface_source": {"kind": "surface_fit", "job_id": "j0"}, "surface": {}, "offset_curve": {},
                      "program": {"lines": 1}, "nominal_program": {"lines": 1}}


def test_the_five_axis_result_declares_only_the_jobs_own_fields_beside_the_cores_figures():
    core = typing.get_type_hints(FiveAxisFigures)
    result = FiveAxisResult.model_fields
    assert set(core) == {f.name for f in fields(FiveAxisFigures)}
    assert all(result[name].annotation == kind for name, kind in core.items())
    assert set(result) - set(core) == set(FIVE_AXIS_JOB_KEYS)
    assert set(result) == FIVE_AXIS_KEYS  # the stored shape stays flat, key for key


def test_a_planned_paths_figures_round_trip_through_the_stored_result():
    surface = sphere_cap()
    t = np.linspace(0, 2 * np.pi, 40)
    trace = trace_over_xy(surface, np.column_stack([4.0 + 14.0 * np.cos(t), 2.0 + 9.0 * np.sin(t)]))
    path = plan_five_axis(surface, trace, FiveAxisParams(standoff_mm=0.5, feed_mm_min=1200, period_s=0.002,
                                                         segment_mm=2.0, pivot=(5.0, -3.0, -20.0)))
    stored = json.loads(json.dumps(FiveAxisResult.written({**asdict(path.figures), **FIVE_AXIS_JOB_KEYS})))
    assert set(stored) == FIVE_AXIS_KEYS
    typed = FiveAxisResult.of_record({"id": "j1", "kind": "five_axis", "result": stored})
    assert FiveAxisFigures(**{f.name: getattr(typed, f.name) for f in fields(FiveAxisFigures)}) == path.figures
    assert typed.lines == path.u.size and typed.post == "conforma"


def _counts(value: object) -> PathCounts:
    return PathCounts(**{f.name: getattr(value, f.name) for f in fields(PathCounts)})


def test_the_toolpath_results_compose_the_cores_path_counts():
    counts = typing.get_type_hints(PathCounts)
    layer = {f.name: f.type for f in fields(ToolpathLayer)}
    assert set(layer) - set(counts) == {"index", "z", "thickness", "time_s", "planner_time_s", "pieces"}
    assert set(ToolpathResult.model_fields) - set(counts) == {
        "time_s", "planner_time_s", "estimator", "pattern", "layer_count", "program", "placement", "layers"}
    assert all(ToolpathResult.model_fields[name].annotation == kind for name, kind in counts.items())
    assert all(typing.get_type_hints(ToolpathLayer)[name] == kind for name, kind in counts.items())


def test_a_planned_layers_counts_round_trip_through_the_stored_layer():
    toolpath = plan_toolpath(slice_mesh(trimesh.creation.box((12.0, 8.0, 1.0)), SliceParams(layer_mm=0.5)))
    layer = toolpath.layers[0]
    assert layer.stats.path_mm > 0 and layer.stats.turns > 0
    row = {"index": layer.index, "z": layer.z, "thickness": layer.thickness, **asdict(_counts(layer.stats)),
           "time_s": 1.5, "planner_time_s": layer.stats.time_s, "pieces": len(layer.pieces)}
    adapter = TypeAdapter(ToolpathLayer)
    stored = json.loads(adapter.dump_json(adapter.validate_python(row)))
    assert stored == row
    assert _counts(adapter.validate_python(stored)) == _counts(layer.stats)


def test_the_calibration_results_compose_the_cores_calibrations():
    for result, core, own in (
            (CalibrateProbeResult, ProbeCalibration, {"agreement", "nominal_ball_radius_mm", "readings"}),
            (CalibrateNozzleResult, NozzleCalibration, {"agreement", "nominal_offset_mm", "nominal_difference_mm",
                                                        "probe_job_id", "readings"}),
            (CalibrateSensorResult, SensorCalibration, {"sensor_port", "sensor_rate_hz", "references", "report"})):
        hints = typing.get_type_hints(core)
        assert set(result.model_fields) - set(hints) == own
        assert all(result.model_fields[name].annotation == kind for name, kind in hints.items())
        assert {name for name, f in result.model_fields.items() if not f.is_required()} >= {
            f.name for f in fields(core) if f.default is not MISSING or f.default_factory is not MISSING}


def test_a_calibration_round_trips_through_the_stored_result():
    probe = ProbeCalibration(ball_radius_mm=0.498, pretravel=PretravelModel(0.012, 0.001, -0.002),
                             sphere_centre_mm=(10.0, 20.0, -5.5), pad_reading_z_mm=1.25,
                             std={"ball_radius_mm": 5e-4}, residual_rms_mm=0.001, touches=40, drift_mm_per_min=0.002)
    stored = json.loads(json.dumps(CalibrateProbeResult.written(probe.to_dict())))
    assert stored == probe.to_dict()
    assert CalibrateProbeResult.of_record({"id": "j", "kind": "calibrate_probe", "result": stored}).calibration() \
        == probe
    without_std = {k: v for k, v in stored.items() if k != "std"}
    assert CalibrateProbeResult.of_record({"id": "j", "kind": "calibrate_probe", "result": without_std}).std == {}
    nozzle = NozzleCalibration(tool=2, offset_mm=(1.25, -0.5, 3.0), std_mm=(1e-3, 2e-3, 3e-3), outer_diameter_mm=0.8,
                               touches=14)
    stored = json.loads(json.dumps(CalibrateNozzleResult.written({**nozzle.to_dict(), "probe_job_id": "jp"})))
    assert stored == {**nozzle.to_dict(), "probe_job_id": "jp"}
    assert CalibrateNozzleResult.of_record({"id": "j", "kind": "calibrate_nozzle", "result": stored}).calibration() \
        == nozzle
    sensor = SensorCalibration(offset_mm=(0.1, -0.2, 12.5), scale=1.002, time_offset_s=0.004, slope_bias_mm=0.01,
                               sd={"scale": 1e-4})
    stored = json.loads(json.dumps(CalibrateSensorResult.written(sensor.to_dict())))
    assert stored == sensor.to_dict()
    assert CalibrateSensorResult.of_record({"id": "j", "kind": "calibrate_sensor", "result": stored}).calibration() \
        == sensor


def test_the_jetting_results_compose_the_cores_figures():
    qp = typing.get_type_hints(QpFigures)
    assert set(NextLayerResult.model_fields) - set(qp) == {"drops", "reference_height_um", "measured_layer", "grid"}
    assert all(NextLayerResult.model_fields[name].annotation == kind for name, kind in qp.items())
    assert {f.name for f in fields(JettingLayer)} == {f.name for f in fields(LayerSolve)} | {
        f.name for f in fields(SurfaceMetrics)}


def test_a_layer_decisions_figures_round_trip_through_the_stored_result():
    params = JettingParams(target=TargetSpec(size_mm=2, hole_mm=0))
    target = target_from_spec(params.target, params.drop)
    measured = target.mask * (10 * params.controller.fill * params.drop.layer_mm)
    decision = next_layer(measured, target, params)
    figures = {f.name: getattr(decision, f.name) for f in fields(QpFigures)}
    assert decision.solve_ms > 0 and decision.integer_gap >= -1e-9
    grid = {"shape": list(target.shape), "pitch_mm": target.pitch_mm, "part_cells": int(target.mask.sum()),
            "layer_height_um": 10.0}
    own = {"drops": int(decision.pattern.sum()), "reference_height_um": decision.level_mm * 1e3,
           "measured_layer": None, "grid": grid}
    stored = json.loads(json.dumps(NextLayerResult.written({**figures, **own})))
    assert stored == {**figures, **own}
    typed = NextLayerResult.of_record({"id": "j", "kind": "jetting_next_layer", "result": stored})
    assert QpFigures(**{name: getattr(typed, name) for name in figures}) == QpFigures(**figures)


WARP_JOB_KEYS = {"model_error_mm": 0.001, "fixed_split": {"split_mm": 5.0, "pieces": 3, "max_error_mm": 0.01}}


def test_the_warp_result_composes_the_cores_figures():
    core = typing.get_type_hints(WarpFigures)
    assert set(WarpProgramResult.model_fields) - set(core) == {"model_error_mm", "height_model", "fixed_split"}
    assert all(WarpProgramResult.model_fields[name].annotation == kind for name, kind in core.items())


def test_a_warps_figures_round_trip_through_the_stored_result():
    x, y = np.linspace(0, 60, 13), np.linspace(0, 40, 9)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    surface = HeightField(x, y, 3.0 + 0.002 * xx**2 - 0.0004 * xx * yy)
    program = "G21\nG90\nM83\nG0 X5 Y5\nG1 Z0.2\nG1 X45 Y15 E1.0 F600\nG1 X10 Y25 E0.5\n"
    warped = warp_program(program, surface, WarpOptions(standoff_mm=0.1, chord_error_mm=0.002))
    figures = {f.name: getattr(warped, f.name) for f in fields(WarpFigures)}
    assert figures["printing_moves"] == 2 and 0 < figures["max_chord_bound_mm"] <= 0.002
    stored = json.loads(json.dumps(WarpProgramResult.written({**figures, **WARP_JOB_KEYS})))
    assert stored == {**figures, **WARP_JOB_KEYS}
    typed = WarpProgramResult.of_record({"id": "j", "kind": "warp_program", "result": stored})
    assert WarpFigures(**{name: getattr(typed, name) for name in figures}) == WarpFigures(**figures)
