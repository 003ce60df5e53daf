"""The closed loop under faults: each gives a clear error or a documented recovery, and
no compensated program is ever made from bad data."""

from __future__ import annotations

import time

import numpy as np
import pytest
from sqlalchemy import update

from app.models import Job
from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.jobs.test_jobs_api import wait_for

OP = auth("operator")


@pytest.fixture(scope="module")
def stls():
    return (s1_mesh(grid_mm=0.5).export(file_type="stl"),
            as_made(seed=4, amplitude_mm=0.15).mesh(grid_mm=0.5).export(file_type="stl"))


@pytest.fixture
def setup(client, stls):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", stls[0])}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", stls[1])}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[4].to_api(), headers=OP).json()
    return part, real, trace


def machine(client, **mock) -> dict:
    return client.post("/api/v1/machines", json={"name": "m", "port": "mock://", "dialect": "marlin", "mock": mock},
                       headers=OP).json()


def job(client, kind: str, params: dict, timeout: float = 60) -> dict:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    return wait_for(client, response.json()["id"], timeout=timeout)


def plan(client, trace: dict, **extra) -> dict:
    return job(client, "probe_plan", {"trace_id": trace["id"], "method": "uniform", "count": 8, **extra})


def test_a_probe_that_does_not_trigger_fails_the_run_and_the_loop_makes_no_program(client, setup):
    part, _real, trace = setup
    flat_bed = machine(client)  # no true part: nothing but the bed, far below the expected surface
    run = job(client, "probe_run", {"plan_job_id": plan(client, trace)["id"], "machine_id": flat_bed["id"]})
    assert run["status"] == "failed" and run["error"]["status"] == 422
    assert "found no surface" in run["error"]["detail"] and run["result"] is None
    loop = job(client, "closed_loop", {"part_id": part["id"], "trace_ids": [trace["id"]],
                                       "machine_id": flat_bed["id"]})
    assert loop["status"] == "failed" and "probe_run" in loop["error"]["detail"]
    kinds = [j["kind"] for j in client.get(f"/api/v1/jobs?parent_id={loop['id']}", headers=OP).json()["items"]]
    assert "compensate" not in kinds and "reconstruct" not in kinds


def test_a_disconnect_mid_probe_run_waits_for_the_operator_then_resumes(client, setup):
    _part, real, trace = setup
    flaky = machine(client, true_part_id=real["id"], faults={"disconnect_at_line": 12})
    clean = machine(client, true_part_id=real["id"])
    probe_plan = plan(client, trace)
    run = client.post("/api/v1/jobs", json={"kind": "probe_run", "params": {
        "plan_job_id": probe_plan["id"], "machine_id": flaky["id"]}}, headers=OP).json()
    interrupted = wait_for(client, run["id"], states=("interrupted", "succeeded", "failed"))
    assert interrupted["status"] == "interrupted", interrupted
    state = interrupted["program_state"]
    assert 0 < state["executed"] < 8 and len(state["points"]) == state["executed"] and state["reason"]
    executed = client.get(f"/api/v1/machines/{flaky['id']}", headers=OP).json()["mock"]["executed_commands"]
    time.sleep(0.5)  # nobody asked: nothing moves
    assert client.get(f"/api/v1/machines/{flaky['id']}", headers=OP).json()["mock"]["executed_commands"] == executed
    assert client.get(f"/api/v1/jobs/{run['id']}", headers=OP).json()["status"] == "interrupted"
    refused = client.post(f"/api/v1/jobs/{run['id']}/resume", json={"confirm": False}, headers=OP)
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"] == ["confirm"]
    assert client.post(f"/api/v1/jobs/{run['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
    resumed = wait_for(client, run["id"], timeout=60)
    reference = job(client, "probe_run", {"plan_job_id": probe_plan["id"], "machine_id": clean["id"]})
    assert resumed["status"] == "succeeded", resumed["error"]
    assert resumed["result"]["resumes"] == 1
    got = np.array([p["measured"] for p in resumed["result"]["points"]])
    want = np.array([p["measured"] for p in reference["result"]["points"]])
    assert got.shape == want.shape == (8, 3) and np.allclose(got, want, atol=1e-9)  # noise-free mock
    assert client.post(f"/api/v1/jobs/{run['id']}/resume", json={"confirm": True}, headers=OP).status_code == 409


def test_a_far_off_measurement_is_rejected_as_an_outlier(client, setup):
    _part, _real, trace = setup
    truth = as_made(seed=4, amplitude_mm=0.15)
    xy = np.array(plan(client, trace, count=12)["result"]["points"])[:, :2]
    measured = np.column_stack([xy, truth.true_height(xy)])
    measured[5, 2] += 0.5
    rebuilt = job(client, "reconstruct", {"trace_id": trace["id"], "points": measured.tolist(), "method": "deviation"})
    assert rebuilt["status"] == "succeeded" and rebuilt["result"]["outliers"] == [5]
    assert rebuilt["result"]["deviation"]["max_mm"] < 0.3


def test_a_trace_outside_the_probed_span_gets_no_compensated_program(client, setup):
    _part, _real, trace = setup
    nominal = np.array(trace["nominal"]["points"])
    middle = nominal[len(nominal) // 4: 3 * len(nominal) // 4: max(1, len(nominal) // 16)]
    rebuilt = job(client, "reconstruct", {"trace_id": trace["id"], "points": middle.tolist(), "method": "deviation"})
    assert rebuilt["status"] == "succeeded", rebuilt["error"]
    compensated = job(client, "compensate", {"trace_id": trace["id"], "reconstruct_job_id": rebuilt["id"]})
    assert compensated["status"] == "failed" and compensated["error"]["status"] == 422
    assert "probes cover only" in compensated["error"]["detail"] and compensated["artifacts"] == []


def test_closed_loop_cancel_stops_it_and_a_retried_loop_reuses_finished_children(client, setup):
    part, real, trace = setup
    slow = machine(client, true_part_id=real["id"], time_scale=1.0)
    response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": slow["id"]}}, headers=OP)
    loop_id = response.json()["id"]
    wait_for(client, loop_id, states=("running",))
    children = []
    while not any(c["kind"] == "probe_run" for c in children):
        children = client.get(f"/api/v1/jobs?parent_id={loop_id}", headers=OP).json()["items"]
    assert client.post(f"/api/v1/jobs/{loop_id}/cancel", headers=OP).status_code == 202
    assert wait_for(client, loop_id)["status"] == "cancelled"
    run = next(c for c in children if c["kind"] == "probe_run")
    assert wait_for(client, run["id"])["status"] == "cancelled"

    fast = machine(client, true_part_id=real["id"])
    params = {"part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": fast["id"]}
    first = job(client, "closed_loop", params)
    assert first["status"] == "succeeded", first["error"]
    before = client.get(f"/api/v1/jobs?parent_id={first['id']}", headers=OP).json()["total"]
    runtime = client.app.state.runtime  # the parent's worker "died": the reaper would requeue it like this
    with runtime.engine.begin() as conn:
        conn.execute(update(Job).where(Job.id == first["id"]).values(status="queued", result=None, finished_at=None))
    runtime.enqueue(first["id"], "workflow")
    again = wait_for(client, first["id"])
    assert again["status"] == "succeeded" and again["attempts"] == 2
    assert client.get(f"/api/v1/jobs?parent_id={first['id']}", headers=OP).json()["total"] == before
    assert again["result"]["traces"] == first["result"]["traces"]


def test_a_running_loop_holds_its_machine_against_other_programs(client, setup):
    part, real, trace = setup
    slow = machine(client, true_part_id=real["id"], time_scale=1.0)
    loop = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": slow["id"]}}, headers=OP).json()
    wait_for(client, loop["id"], states=("running",))
    program = client.post("/api/v1/programs", files={"file": ("p.gcode", b"G21\nG90\nG0 X1\n")}, headers=OP).json()
    refused = client.post(f"/api/v1/machines/{slow['id']}/print", json={"program_id": program["id"]}, headers=OP)
    assert refused.status_code == 409 and "closed_loop" in refused.json()["detail"]
    client.post(f"/api/v1/jobs/{loop['id']}/cancel", headers=OP)
    assert wait_for(client, loop["id"])["status"] == "cancelled"
    allowed = client.post(f"/api/v1/machines/{slow['id']}/print", json={"program_id": program["id"]}, headers=OP)
    assert allowed.status_code == 202
    assert wait_for(client, allowed.json()["id"])["status"] == "succeeded"
