"""A closed loop's pause points through the API on the mock machine: the loop waits as a
job state (no worker, nothing moves), an operator continues, accepts or abandons it over
HTTP, and a restart of the service while it waits keeps it waiting at the same point."""

from __future__ import annotations

import time

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
ALL = ["plan", "probed", "verified", "print"]
WAITING = ("waiting", "succeeded", "needs_attention", "failed", "cancelled", "interrupted")


@pytest.fixture(scope="module")
def stls() -> tuple[bytes, bytes]:
    return (s1_mesh(grid_mm=0.5).export(file_type="stl"),
            as_made(seed=4, amplitude_mm=0.15).mesh(grid_mm=0.5).export(file_type="stl"))


def _setup(client, stls) -> tuple[dict, dict, dict]:  # type: ignore[no-untyped-def]
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", stls[0])}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", stls[1])}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[4].to_api(), headers=OP).json()
    machine = client.post("/api/v1/machines", json={"name": "m", "port": "mock://", "dialect": "marlin", "mock": {
        "true_part_id": real["id"], "probe_noise_mm": 0.001}}, headers=OP).json()
    return part, trace, machine


def _loop(client, part: dict, trace: dict, machine: dict, **extra) -> dict:  # type: ignore[no-untyped-def]
    response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": machine["id"], "joint_probing": True,
        "sequential": False, "print": True, "pause_at": ALL, **extra}}, headers=OP)
    assert response.status_code == 202, response.text
    return response.json()  # type: ignore[no-any-return]


def _executed(client, machine: dict) -> int:  # type: ignore[no-untyped-def]
    """Commands the mock executed (0 before it was first connected)."""
    return int((client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json().get("mock") or {})
               .get("executed_commands", 0))


def _children(client, loop_id: str) -> list[dict]:  # type: ignore[no-untyped-def]
    return client.get(f"/api/v1/jobs?parent_id={loop_id}&limit=100", headers=OP).json()["items"]  # type: ignore[no-any-return]


def _waits_at(client, loop_id: str, point: str) -> dict:  # type: ignore[no-untyped-def]
    job = wait_for(client, loop_id, states=WAITING, timeout=120)
    assert job["status"] == "waiting", (job["status"], job["error"], job["message"])
    assert job["program_state"]["waiting"]["at"] == point, job["program_state"]
    assert job["message"].startswith(f"waiting at {point}")
    return job


def test_the_loop_waits_at_each_pause_point_and_goes_on_only_when_an_operator_says(client, stls):
    part, trace, machine = _setup(client, stls)
    loop = _loop(client, part, trace, machine)
    waiting = _waits_at(client, loop["id"], "plan")
    summary = waiting["program_state"]["waiting"]["summary"]
    plans = [j for j in _children(client, loop["id"]) if j["kind"] == "probe_plan"]
    assert summary["touches"] == plans[0]["result"]["count"] > 0 and summary["plans"] == [plans[0]["id"]]
    assert {j["kind"] for j in _children(client, loop["id"])} == {"probe_plan"}     # nothing moved
    assert client.get("/api/v1/jobs?kind=closed_loop&status=waiting", headers=OP).json()["total"] == 1
    before = _executed(client, machine)
    time.sleep(0.5)
    assert _executed(client, machine) == before and client.get(
        f"/api/v1/jobs/{loop['id']}", headers=OP).json()["status"] == "waiting"
    # the loop holds its machine while it waits: another loop on it is refused, naming the waiting one
    other = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": machine["id"]}}, headers=OP)
    assert other.status_code == 409 and loop["id"] in other.json()["detail"] and "continue" in other.json()["detail"]
    refused = client.post(f"/api/v1/jobs/{loop['id']}/accept", headers=OP)   # nothing to accept at the plan
    assert refused.status_code == 409 and "nothing needs accepting" in refused.json()["detail"]

    assert client.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 202
    probed = _waits_at(client, loop["id"], "probed")
    runs = [j for j in _children(client, loop["id"]) if j["kind"] == "probe_run"]
    assert runs and all(j["status"] == "succeeded" for j in runs)
    assert probed["program_state"]["waiting"]["summary"]["runs"][-1] == runs[0]["id"]
    assert probed["program_state"]["passed"] == ["plan"]
    assert not any(j["kind"] == "reconstruct" for j in _children(client, loop["id"]))

    assert client.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 202
    verified = _waits_at(client, loop["id"], "verified")
    check = verified["program_state"]["waiting"]
    verdict = check["summary"]["verdict"]
    assert "verified at 5 points" in verdict["verified"] and check["needs_attention"] == verdict["needs_attention"]
    printed_before = _executed(client, machine)
    if check["needs_attention"]:  # a failed verification is accepted explicitly, never continued past
        refused = client.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP)
        assert refused.status_code == 409 and "accept" in refused.json()["detail"]
        assert client.post(f"/api/v1/jobs/{loop['id']}/accept", headers=OP).status_code == 202
    else:
        assert client.post(f"/api/v1/jobs/{loop['id']}/accept", headers=OP).status_code == 409
        assert client.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 202
    _waits_at(client, loop["id"], "print")
    assert _executed(client, machine) == printed_before                          # nothing printed yet
    assert not any(j["kind"] == "print" for j in _children(client, loop["id"]))

    assert client.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 202
    done = wait_for(client, loop["id"], timeout=120)
    assert done["status"] == "succeeded", done["error"]
    assert done["program_state"]["passed"] == sorted(["plan", "probed", "verified", "print"])
    kinds = [j["kind"] for j in _children(client, loop["id"])]
    assert kinds.count("probe_run") == len(runs) and kinds.count("print") == 1   # one run, never probed again
    assert _executed(client, machine) > printed_before
    [entry] = done["result"]["traces"]
    assert entry["print"] in {j["id"] for j in _children(client, loop["id"]) if j["kind"] == "print"}
    assert client.get(f"/api/v1/jobs/{loop['id']}/report", headers=OP).status_code == 200
    assert client.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 409


def test_a_waiting_loop_is_abandoned_and_frees_its_machine(client, stls):
    part, trace, machine = _setup(client, stls)
    loop = _loop(client, part, trace, machine)
    _waits_at(client, loop["id"], "plan")
    abandoned = client.post(f"/api/v1/jobs/{loop['id']}/abandon", headers=OP)
    assert abandoned.status_code == 200 and abandoned.json()["status"] == "cancelled"
    assert client.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 409
    again = _loop(client, part, trace, machine)                                   # the machine is free
    _waits_at(client, again["id"], "plan")
    assert client.post(f"/api/v1/jobs/{again['id']}/cancel", headers=OP).json()["status"] == "cancelled"


def test_the_api_default_does_not_pause_and_a_bad_pause_point_is_named(client, stls):
    part, trace, machine = _setup(client, stls)
    refused = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": machine["id"], "pause_at": ["later"]}},
        headers=OP)
    assert refused.status_code == 422 and refused.json()["errors"][0]["loc"][:2] == ["params", "pause_at"]
    plain = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": machine["id"]}}, headers=OP).json()
    done = wait_for(client, plain["id"], states=WAITING, timeout=120)
    assert done["status"] == "succeeded", done["error"]
    not_loop = client.post(f"/api/v1/jobs/{done['result']['traces'][0]['compensate']}/continue", headers=OP)
    assert not_loop.status_code == 409 and "only a closed loop" in not_loop.json()["detail"]


def test_a_restart_while_waiting_keeps_the_loop_at_the_same_point(settings, stls):
    with TestClient(create_app(settings), raise_server_exceptions=False) as first:
        part, trace, machine = _setup(first, stls)
        loop = _loop(first, part, trace, machine)
        _waits_at(first, loop["id"], "plan")
        assert first.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 202
        _waits_at(first, loop["id"], "probed")
        runs = [j["id"] for j in _children(first, loop["id"]) if j["kind"] == "probe_run"]
    with TestClient(create_app(settings), raise_server_exceptions=False) as second:  # the service restarted
        time.sleep(0.5)
        job = second.get(f"/api/v1/jobs/{loop['id']}", headers=OP).json()
        assert job["status"] == "waiting" and job["program_state"]["waiting"]["at"] == "probed"
        assert second.post(f"/api/v1/jobs/{loop['id']}/continue", headers=OP).status_code == 202
        _waits_at(second, loop["id"], "verified")
        assert [j["id"] for j in _children(second, loop["id"]) if j["kind"] == "probe_run"] == runs  # not again
        assert second.post(f"/api/v1/jobs/{loop['id']}/abandon", headers=OP).json()["status"] == "cancelled"


def test_add_stations_at_the_verified_point_plans_one_more_round_from_the_run(client, stls):
    part, trace, machine = _setup(client, stls)
    loop = _loop(client, part, trace, machine, pause_at=["verified"])
    first = _waits_at(client, loop["id"], "verified")
    runs = [j for j in _children(client, loop["id"]) if j["kind"] == "probe_run"]
    last_run = runs[0]["id"]                                              # newest first
    learned = first["program_state"]["waiting"]["summary"]["verdict"]["suggested_probe"]
    too_early = client.post(f"/api/v1/jobs/{loop['id']}/add-stations", json={"touch_budget": 0}, headers=OP)
    assert too_early.status_code == 422 and too_early.json()["errors"][0]["loc"][-1] == "touch_budget"
    assert client.post(f"/api/v1/jobs/{loop['id']}/add-stations", headers=OP).status_code == 202
    again = _waits_at(client, loop["id"], "verified")
    assert again["program_state"]["waiting"]["key"] == "verified@1"
    [replan] = again["program_state"]["replans"]
    assert {k: replan[k] for k in learned} == learned                     # planned from the learned prior
    plans = [j for j in _children(client, loop["id"]) if j["kind"] == "probe_plan"
             and j["params"].get("fixed_run_job_id") == last_run and not j["params"].get("retouch_only")]
    assert len(plans) == 1 and plans[0]["params"]["deviation_wavelength_mm"] == learned["deviation_wavelength_mm"]
    kinds = [j["kind"] for j in _children(client, loop["id"])]
    assert kinds.count("probe_run") == len(runs) + (1 if plans[0]["result"]["count"] else 0)
    assert client.post(f"/api/v1/jobs/{loop['id']}/abandon", headers=OP).json()["status"] == "cancelled"
