"""The typed results of circuit_program, warp_program, toolpath, jetting, jetting_next_layer
(and print, whose PrintResult its kind now writes through): a stored result missing a required
field is a StoredResultError naming ``result.<field>``; a kind writing an unknown or missing key
fails instead of storing it.  That the real kinds' results round-trip through their models to
exactly the stored JSON is checked where the kinds run (:func:`round_trips`, used by
test_jetting_jobs, test_circuit_jobs, test_slicing_jobs, test_nozzle_frame, e2e/test_circuit_loop)."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from app.jobs.results.jetting import JettingResult, NextLayerResult
from app.jobs.results.models import KindResult, PrintResult, StoredResultError
from app.jobs.results.program import CircuitProgramResult, ToolpathResult, WarpProgramResult
from app.platform.models import Job, utcnow


def round_trips(model: type[KindResult], job: dict) -> KindResult:
    """``job`` (the API's job record) read through ``model``, asserting that its stored result is
    exactly what the model dumps again (JSON form, only the keys the kind set)."""
    typed = model.of_record(job)
    assert typed.model_dump(mode="json", exclude_unset=True) == job["result"]
    return typed


GRID = {"shape": [40, 40], "pitch_mm": 0.17, "part_cells": 700, "layer_height_um": 10.0}
METRICS = {"sa_um": 1.0, "sa_interior_um": 0.5, "sz_um": 4.0, "rmse_um": 1.2, "edge_collapse_um": 0.1,
           "edge_collapse_outer_um": 0.1, "edge_collapse_hole_um": 0.0, "mean_height_um": 10.0,
           "target_height_um": 10.0}
LAYER = {"layer": 1, **METRICS, "drops": 600, "solve_ms": 5.0, "solve_cpu_ms": 5.0, "iterations": 30,
         "integer_gap": 0.01, "kkt_residual": 1e-6}
JETTING = {"layers": [LAYER], "final": LAYER, "grid": GRID, "controller": "mpc", "solve_ms_median": 5.0,
           "pattern_pngs": ["pattern_0001.png"]}
NEXT = {"drops": 600, "integer_gap": 0.01, "kkt_residual": 1e-6, "solve_ms": 5.0, "solve_cpu_ms": 5.0,
        "iterations": 30, "flips": 2, "objective_relaxed": 1.0, "objective_binary": 1.1,
        "reference_height_um": 20.0, "measured_layer": None, "grid": GRID}
CIRCUIT = {"strokes": 4, "traces": 2, "fill_strokes": 2, "pad_probe_traces": ["t9"], "stations": 30,
           "travel_mm": 10.0, "travel_input_order_mm": 12.0, "order": [[0, False], [1, True]],
           "dispense_on": "M106", "dispense_off": "M107"}
WARP = {"lines_in": 11, "lines_out": 40, "printing_moves": 3, "pieces": 30, "max_chord_bound_mm": 0.002,
        "safe_z_mm": 9.0, "fixed_split": {"split_mm": 5.0, "pieces": 12, "max_error_mm": 0.01}}
TP_LAYER = {"index": 0, "z": 0.75, "thickness": 1.5, "path_mm": 100.0, "travel_mm": 5.0, "turns": 10, "jumps": 1,
            "time_s": 20.0, "planner_time_s": 19.0, "pieces": 3}
TOOLPATH = {"time_s": 20.0, "planner_time_s": 19.0,
            "estimator": {"name": "estimate_gcode", "description": "planner", "limits": {"accel_mm_s2": 800.0}},
            "pattern": "raster", "layer_count": 1, "path_mm": 100.0, "travel_mm": 5.0, "turns": 10, "jumps": 1,
            "program": {"lines": 50},
            "placement": {"xy": "center", "offset_mm": [0.0, 0.0], "drop_to_bed": True, "shift_mm": [1.0, 2.0, 0.0],
                          "volume_mm": {"x": [0, 200], "y": [0, 200], "z": [0, 200], "source": "default"},
                          "note": "moved"},
            "layers": [TP_LAYER]}
PRINT = {"executed": 3, "total": 3, "start_line": 0, "resumes": 0, "resume_preamble": [], "elapsed_s": 1.0,
         "program": {}, "link": {}}

CASES = [(JettingResult, "jetting", JETTING), (NextLayerResult, "jetting_next_layer", NEXT),
         (CircuitProgramResult, "circuit_program", CIRCUIT), (WarpProgramResult, "warp_program", WARP),
         (ToolpathResult, "toolpath", TOOLPATH)]


def _job(kind: str, result: dict) -> Job:
    return Job(id=f"job_{kind}", kind=kind, status="succeeded", params={}, result=result, created_at=utcnow())


@pytest.mark.parametrize(("model", "kind", "result"), CASES)
def test_each_model_reads_back_what_it_wrote(model, kind, result):
    assert json.loads(json.dumps(model.written(dict(result)))) == result  # as the store keeps it
    assert model.of(_job(kind, result)).model_dump(mode="json", exclude_unset=True) == result


@pytest.mark.parametrize(("model", "kind", "result", "key"), [
    (JettingResult, "jetting", JETTING, "final"),
    (JettingResult, "jetting", JETTING, "pattern_pngs"),
    (NextLayerResult, "jetting_next_layer", NEXT, "measured_layer"),
    (NextLayerResult, "jetting_next_layer", NEXT, "drops"),
    (CircuitProgramResult, "circuit_program", CIRCUIT, "order"),
    (WarpProgramResult, "warp_program", WARP, "fixed_split"),
    (ToolpathResult, "toolpath", TOOLPATH, "layers"),
    (ToolpathResult, "toolpath", TOOLPATH, "placement"),
])
def test_a_stored_result_missing_a_field_names_it(model, kind, result, key):
    broken = {k: v for k, v in result.items() if k != key}
    with pytest.raises(StoredResultError) as caught:
        model.of(_job(kind, broken))
    assert caught.value.field == f"result.{key}"


@pytest.mark.parametrize(("model", "kind", "result", "path", "field"), [
    (JettingResult, "jetting", JETTING, ("grid", "part_cells"), "result.grid.part_cells"),
    (JettingResult, "jetting", JETTING, ("final", "drops"), "result.final.drops"),
    (WarpProgramResult, "warp_program", WARP, ("fixed_split", "max_error_mm"), "result.fixed_split.max_error_mm"),
    (ToolpathResult, "toolpath", TOOLPATH, ("placement", "shift_mm"), "result.placement.shift_mm"),
])
def test_a_nested_missing_field_names_its_path(model, kind, result, path, field):
    outer, inner = path
    broken = {**result, outer: {k: v for k, v in result[outer].items() if k != inner}}
    with pytest.raises(StoredResultError) as caught:
        model.of(_job(kind, broken))
    assert caught.value.field == field


@pytest.mark.parametrize(("model", "kind", "result"), CASES + [(PrintResult, "print", PRINT)])
def test_a_kind_writing_an_unknown_or_missing_key_fails(model, kind, result):
    with pytest.raises(ValidationError):
        model.written({**result, "renamed_mm": 1.0})
    with pytest.raises(ValidationError):
        model.written({k: v for k, v in list(result.items())[1:]})


def test_a_result_of_another_kind_is_refused():
    with pytest.raises(StoredResultError) as caught:
        WarpProgramResult.of(_job("toolpath", TOOLPATH))
    assert caught.value.field == "kind"
