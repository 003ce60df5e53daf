"""The typed results added for the kinds read back by other code (closed_loop, slice,
surface_fit, print, calibrate_probe, calibrate_nozzle): a stored result missing a field, or
with a renamed one, is a StoredResultError naming ``result.<field>`` (through the API: a
400 problem naming it), never an empty default."""

from __future__ import annotations

import pytest
from sqlmodel import Session

from app.jobs.results.calibration import CalibrateNozzleResult, CalibrateProbeResult
from app.jobs.results.five_axis import FiveAxisResult
from app.jobs.results.loop import ClosedLoopResult
from app.jobs.results.models import (
    PrintResult,
    ProgramEcho,
    RegisterResult,
    SliceResult,
    StoredResultError,
    SurfaceFitResult,
)
from app.platform.models import Job, new_id, utcnow
from app.platform.problems import http_status
from app.reporting.collect import RunRecords
from app.reporting.html import render_run_report
from tests.jobs.test_slicing_jobs import box_with_hole, submit, upload

LOOP_ROW = {"trace_id": "t1", "probe_plan": "j1", "probe_run": "j2", "reconstruct": "j3", "compensate": "j4",
            "probes": 12, "deviation_max_mm": 0.05}
SLICE = {"mode": "uniform", "layer_count": 3, "z_min": 0.0, "z_max": 3.0, "bounds": [[0, 0, 0], [20, 12, 3]],
         "frame": "part", "volume_mm3": 600.0, "repairs": [], "notes": [], "beam": {}, "slc": {}, "svg": {},
         "layers": []}
PROBE_CAL = {"ball_radius_mm": 0.5, "pretravel": {"p0_mm": 0.01, "cos3_mm": 0.0, "sin3_mm": 0.0},
             "sphere_centre_mm": [0.0, 0.0, 0.0], "pad_reading_z_mm": 1.0, "std": {"ball_radius_mm": 0.0005},
             "residual_rms_mm": 0.001, "touches": 40, "drift_mm_per_min": None,
             "agreement": {"previous_job_id": "job_old", "differences_mm": {"ball_radius_mm": 0.004},
                           "disagrees": ["ball_radius_mm"]}, "nominal_ball_radius_mm": 0.5, "readings": []}


def _job(kind: str, result: dict | None, params: dict | None = None, status: str = "succeeded") -> Job:
    return Job(id=f"job_{kind}", kind=kind, status=status, params=params or {}, result=result, created_at=utcnow())


def _missing(model, kind: str, result: dict, key: str) -> StoredResultError:
    broken = {k: v for k, v in result.items() if k != key}
    with pytest.raises(StoredResultError) as caught:
        model.of(_job(kind, broken))
    return caught.value


def test_each_new_model_reads_its_stored_result_by_attribute():
    loop = ClosedLoopResult.of(_job("closed_loop", {"traces": [LOOP_ROW], "table": []}))
    assert loop.by_trace()["t1"].compensate == "j4" and loop.traces[0].program == "print.gcode"
    assert SliceResult.of(_job("slice", SLICE)).bounds == [[0, 0, 0], [20, 12, 3]]
    cal = CalibrateProbeResult.of(_job("calibrate_probe", PROBE_CAL))
    assert cal.agreement.disagrees == ["ball_radius_mm"] and cal.calibration().ball_radius_mm == 0.5
    nozzle = {"tool": 1, "offset_mm": [1.0, 2.0, 3.0], "std_mm": [0.001] * 3, "probe_job_id": "job_p"}
    assert CalibrateNozzleResult.of(_job("calibrate_nozzle", nozzle)).calibration().offset_mm == (1.0, 2.0, 3.0)


@pytest.mark.parametrize(("model", "kind", "result", "key"), [
    (ClosedLoopResult, "closed_loop", {"traces": [LOOP_ROW], "table": []}, "traces"),
    (SliceResult, "slice", SLICE, "layer_count"),
    (SliceResult, "slice", SLICE, "bounds"),
    (CalibrateProbeResult, "calibrate_probe", PROBE_CAL, "ball_radius_mm"),
    (PrintResult, "print", {"executed": 3, "total": 3, "start_line": 0, "resumes": 0, "resume_preamble": [],
                            "elapsed_s": 1.0, "program": {}, "link": {}}, "executed"),
])
def test_a_missing_field_is_a_stored_result_error_naming_it(model, kind, result, key):
    error = _missing(model, kind, result, key)
    assert error.field == f"result.{key}" and model.__name__ in error.message
    assert http_status(error)[0] == 400


def test_a_renamed_nested_field_fails_loudly_instead_of_reading_as_a_default():
    """Before: ``(agreement or {}).get("disagrees") or []`` read a renamed list as no disagreement."""
    renamed = {**PROBE_CAL, "agreement": {"previous_job_id": "job_old", "disagree": ["ball_radius_mm"]}}
    with pytest.raises(StoredResultError) as caught:
        CalibrateProbeResult.of(_job("calibrate_probe", renamed))
    assert caught.value.field == "result.agreement.disagree"
    row = {k: v for k, v in LOOP_ROW.items() if k != "compensate"}
    with pytest.raises(StoredResultError) as caught:
        ClosedLoopResult.of(_job("closed_loop", {"traces": [row], "table": []}))
    assert caught.value.field == "result.traces.0.compensate"
    with pytest.raises(StoredResultError, match="not a surface_fit job"):
        SurfaceFitResult.of(_job("slice", SLICE))


def test_the_run_report_reads_typed_results():
    plan = {"count": 1, "method": "uniform", "points": [[0.0, 0.0, 1.0]], "s_mm": [0.0], "records": [{}],
            "program": {}}
    run = {"points": [{"index": 0, "nominal": [0.0, 0.0, 1.0], "measured": [0.0, 0.0, 1.01], "deviation_mm": 0.01}],
           "resumes": 0, "stats": {"count": 1, "max_abs_mm": 0.01, "mean_mm": 0.01, "rms_mm": 0.01}}
    root = {"id": "job_run", "kind": "probe_run", "status": "succeeded", "created_at": "", "finished_at": "",
            "started_at": "", "params": {"plan_job_id": "job_plan"}, "result": run, "input_hashes": {}}
    records = RunRecords(root=root, jobs=[
        {**root, "id": "job_plan", "kind": "probe_plan", "params": {}, "result": plan}, root])
    page = render_run_report(records, "test")
    assert "<td>1</td>" in page and "10.00" in page  # probes planned / measured, |d| max in um
    renamed = {**run, "stat": run["stats"]}
    del renamed["stats"]
    records.jobs[1] = {**root, "result": renamed}
    with pytest.raises(StoredResultError, match="ProbeRunResult") as caught:
        render_run_report(records, "test")
    assert caught.value.field == "result.stats"


def test_through_the_api_a_broken_stored_slice_is_a_problem_naming_the_field(client):
    part_id = upload(client, box_with_hole())
    broken = {k: v for k, v in SLICE.items() if k != "bounds"}
    with Session(client.app.state.runtime.engine) as session:
        job = Job(id=new_id("job"), kind="slice", status="succeeded", progress=1.0, params={"part_id": part_id},
                  result=broken, created_at=utcnow(), finished_at=utcnow())
        session.add(job)
        session.commit()
        slice_id = job.id
    response = submit(client, "toolpath", {"slice_job_id": slice_id})
    assert response.status_code == 400, response.text
    problem = response.json()
    assert problem["errors"][0]["loc"] == ["result", "bounds"] and "SliceResult" in problem["detail"]


REGISTER = {"placement": {"dx": 1.0, "dy": -2.0, "dz": 0.1, "rz_deg": 0.5, "pivot": [0.0, 0.0]},
            "std": {"dx_mm": 0.001, "dy_mm": 0.001, "dz_mm": 0.001, "rz_deg": 0.002},
            "covariance": {"parameters": ["dx_mm"], "matrix": [[1e-6]]}, "unobservable": [],
            "rms_mm": {"top": 0.001}, "probe_count": 30, "touches": [], "mode": "edges",
            "plan": {"faces": ["+z"], "predicted_std": {}}}


@pytest.mark.parametrize("key", ["placement", "covariance", "probe_count", "mode"])
def test_a_register_result_missing_a_field_names_it(key):
    error = _missing(RegisterResult, "register", REGISTER, key)
    assert error.field == f"result.{key}" and "RegisterResult" in error.message


def test_a_five_axis_result_missing_a_field_names_it():
    with pytest.raises(StoredResultError) as caught:
        FiveAxisResult.of(_job("five_axis", {"lines": 3}))
    assert caught.value.field.startswith("result.") and caught.value.field != "result.lines"
    with pytest.raises(StoredResultError, match="not a five_axis job"):
        FiveAxisResult.of(_job("register", REGISTER))


def test_the_program_echo_of_any_job():
    """Any kind's result: the dispense lines and five-axis frame it echoes, None when absent."""
    echo = ProgramEcho.of_any(_job("compensate", {"dispense_on": "M3 S1", "dispense_off": "M5", "segments": 4}))
    assert (echo.dispense_on, echo.dispense_off, echo.pivot, echo.post) == ("M3 S1", "M5", None, None)
    empty = ProgramEcho.of_any(_job("print", None, status="running"))
    assert empty == ProgramEcho()
    with pytest.raises(StoredResultError) as caught:
        ProgramEcho.of_any(_job("five_axis", {"pivot": "origin", "post": "conforma"}))
    assert caught.value.field == "result.pivot" and http_status(caught.value)[0] == 400
