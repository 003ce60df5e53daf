"""The closed loop under faults: each gives a clear error or a documented recovery, and
no compensated program is ever made from bad data."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from sqlalchemy import update

from app.domain.errors import Cancelled
from app.platform.models import Job
from app.reference.s1 import as_made, s1_mesh, s1_traces
from hardware.mock import get_world
from tests.conftest import auth
from tests.helpers.jobs import wait_for

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


# --- a closed loop whose probe_run child is interrupted --------------------------------------

def touches(machine_id: str) -> list[str]:
    """The probe commands the mock firmware executed (Marlin G30 / G38.2), in order."""
    return [c for c in get_world(machine_id).transcript.commands if c.split(" ")[0] in ("G30", "G38.2")]


def children(client, loop_id: str, kind: str | None = None) -> list[dict]:
    items = client.get(f"/api/v1/jobs?parent_id={loop_id}", headers=OP).json()["items"]
    return [c for c in items if kind is None or c["kind"] == kind]


def wait_interrupted_child(client, loop_id: str, timeout: float = 90) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        stuck = [c for c in children(client, loop_id, "probe_run") if c["status"] == "interrupted"]
        if stuck:
            return stuck[0]
        assert client.get(f"/api/v1/jobs/{loop_id}", headers=OP).json()["status"] in ("queued", "running")
        time.sleep(0.05)
    raise AssertionError("no probe_run child was interrupted")


@pytest.fixture
def two_traces(client, stls, setup):
    part, real, first = setup
    second = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[2].to_api(), headers=OP).json()
    probe = {"method": "uniform", "count": 8}
    # the commands the loop's first probe run executes, counted on a clean machine
    clean = machine(client, true_part_id=real["id"])
    alone = job(client, "closed_loop", {"part_id": part["id"], "trace_ids": [first["id"]], "machine_id": clean["id"],
                                        "probe": probe})
    assert alone["status"] == "succeeded", alone["error"]
    first_run = get_world(clean["id"]).transcript.executed_count
    flaky = machine(client, true_part_id=real["id"], faults={"disconnect_at_line": first_run + 7})
    params = {"part_id": part["id"], "trace_ids": [first["id"], second["id"]], "machine_id": flaky["id"],
              "probe": probe}
    return params, flaky, clean


def reference_points(client, plan_id: str, clean: dict) -> np.ndarray:
    reference = job(client, "probe_run", {"plan_job_id": plan_id, "machine_id": clean["id"]})
    return np.array([p["measured"] for p in reference["result"]["points"]])


def test_a_loop_waits_while_its_probe_run_is_interrupted_and_continues_when_the_operator_resumes_it(
        client, two_traces):
    params, flaky, clean = two_traces
    loop_id = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": params}, headers=OP).json()["id"]
    child = wait_interrupted_child(client, loop_id)
    finished = [c for c in children(client, loop_id, "probe_run") if c["status"] == "succeeded"]
    assert len(finished) == 1 and child["params"]["plan_job_id"] != finished[0]["params"]["plan_job_id"]
    frozen = len(get_world(flaky["id"]).transcript.commands)
    assert 0 < child["program_state"]["executed"] < 8
    time.sleep(0.6)  # nobody asked: nothing moves, the loop only waits
    assert len(get_world(flaky["id"]).transcript.commands) == frozen
    assert client.get(f"/api/v1/jobs/{loop_id}", headers=OP).json()["status"] == "running"
    # the loop itself is not interrupted: resuming it is refused; the operator resumes the step that stopped
    assert client.post(f"/api/v1/jobs/{loop_id}/resume", json={"confirm": True}, headers=OP).status_code == 409
    assert client.post(f"/api/v1/jobs/{child['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, loop_id, timeout=120)
    assert done["status"] == "succeeded", done["error"]
    runs = children(client, loop_id, "probe_run")
    assert len(runs) == 2 and {r["status"] for r in runs} == {"succeeded"}  # the same child, resumed
    resumed = client.get(f"/api/v1/jobs/{child['id']}", headers=OP).json()
    assert resumed["result"]["resumes"] == 1 and done["result"]["traces"][1]["probe_run"] == child["id"]
    got = np.array([p["measured"] for p in resumed["result"]["points"]])
    assert np.allclose(got, reference_points(client, child["params"]["plan_job_id"], clean), atol=1e-9)
    # 16 probes, the one cut by the disconnect touched again (a touch is idempotent), nothing re-probed
    assert len(touches(flaky["id"])) <= 16 + 1


def test_a_loop_and_its_probe_run_both_interrupted_resume_child_first_then_the_loop(client, two_traces, monkeypatch):
    """The server dies while the loop waits for its interrupted probe run: after the restart
    both are interrupted.  Resuming the loop first is refused naming the child; the child
    resumes its probes where they stopped; the loop stays interrupted until the operator
    resumes it, then reuses every finished child and probes nothing again."""
    from app.runtime.context import JobContext

    params, flaky, clean = two_traces
    dead: set[str] = set()
    gone = threading.Event()
    check = JobContext.check_cancelled

    def dead_check(self: JobContext) -> None:  # the loop's first attempt died with its server
        if self.job_id in dead and self.claim.attempt == 1:
            gone.wait()
            raise Cancelled("the process of this attempt is gone", field="job_id", value=self.job_id)
        check(self)

    monkeypatch.setattr(JobContext, "check_cancelled", dead_check)
    loop_id = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": params}, headers=OP).json()["id"]
    child = wait_interrupted_child(client, loop_id)
    dead.add(loop_id)  # from now on its thread does nothing, like a process that is gone
    time.sleep(0.2)
    runtime = client.app.state.runtime
    try:
        assert runtime.store.interrupt_orphans("the-restarted-server:") == [loop_id]  # the restart's sweep
        loop = client.get(f"/api/v1/jobs/{loop_id}", headers=OP).json()
        assert loop["status"] == "interrupted"
        frozen = len(get_world(flaky["id"]).transcript.commands)
        refused = client.post(f"/api/v1/jobs/{loop_id}/resume", json={"confirm": True}, headers=OP)
        assert refused.status_code == 409 and child["id"] in refused.json()["detail"]
        time.sleep(0.5)
        assert len(get_world(flaky["id"]).transcript.commands) == frozen  # a refused resume moves nothing
        assert client.post(f"/api/v1/jobs/{child['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
        resumed = wait_for(client, child["id"], timeout=60)
        assert resumed["status"] == "succeeded", resumed["error"]
        probed = len(touches(flaky["id"]))
        time.sleep(0.3)
        assert client.get(f"/api/v1/jobs/{loop_id}", headers=OP).json()["status"] == "interrupted"
        before = {c["id"] for c in children(client, loop_id)}
        assert client.post(f"/api/v1/jobs/{loop_id}/resume", json={"confirm": True}, headers=OP).status_code == 202
        done = wait_for(client, loop_id, timeout=120)
        assert done["status"] == "succeeded", done["error"]
        assert done["attempts"] == 2 and [t["probe_run"] for t in done["result"]["traces"]][1] == child["id"]
        runs = children(client, loop_id, "probe_run")
        assert len(runs) == 2  # no probe run submitted again: finished traces are never re-probed
        assert len(touches(flaky["id"])) == probed <= 16 + 1  # the loop's resume touched nothing
        new = [c["kind"] for c in children(client, loop_id) if c["id"] not in before]
        # only the steps after probing: every trace is probed before any is rebuilt
        assert sorted(new) == ["compensate"] * 2 + ["reconstruct"] * 2
        got = np.array([p["measured"] for p in resumed["result"]["points"]])
        assert np.allclose(got, reference_points(client, child["params"]["plan_job_id"], clean), atol=1e-9)
    finally:
        gone.set()
