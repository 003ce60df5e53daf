"""The closed loop through the API with the mock printer (issue 5's acceptance case).

S1 reference part, as-made with +-0.15 mm machining error and a 0.03 mm placement offset
in z, 1 um probe noise: every compensated trace holds its standoff within 10 um along the
whole printed length (measured on what the mock really deposited), while the nominal
programs are off by >= 100 um (on the worst trace; >= 50 um on each).
"""

from __future__ import annotations

import pytest

from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.jobs.test_jobs_api import wait_for

OP = auth("operator")
TRACES = (0, 3, 6)  # one line, one R40 arc, one NURBS


@pytest.fixture(scope="module")
def meshes():
    truth = as_made(seed=11, amplitude_mm=0.15)
    return s1_mesh(grid_mm=0.3).export(file_type="stl"), truth.mesh(grid_mm=0.3).export(file_type="stl")


def test_compensated_traces_hold_their_standoff_on_the_real_part(client, meshes):
    nominal_stl, true_stl = meshes
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", nominal_stl)}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("s1-as-made.stl", true_stl)}, headers=OP).json()
    refs = [s1_traces()[i] for i in TRACES]
    traces = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=[t.to_api() for t in refs],
                         headers=OP).json()["items"]
    machine = client.post("/api/v1/machines", json={
        "name": "sim", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "placement": {"dz": 0.03}, "probe_noise_mm": 0.001,
                 "faults": {"seed": 5}}}, headers=OP).json()
    response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": [t["id"] for t in traces], "machine_id": machine["id"],
        "probe": {"method": "deviation"}, "sigma_mm": 0.001, "evaluate": True}}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=240)
    assert done["status"] == "succeeded", done["error"]
    table = done["result"]["table"]
    assert len(table) == len(TRACES)
    for row in table:
        assert row["standoff_max_after_um"] <= 10.0, row
        assert row["standoff_max_before_um"] >= 50.0, row  # where the +-0.15 mm error field peaks varies
        assert row["width_std_after_um"] < row["width_std_before_um"]
    assert max(row["standoff_max_before_um"] for row in table) >= 100.0
    children = client.get(f"/api/v1/jobs?parent_id={done['id']}&limit=100", headers=OP).json()
    kinds = sorted(j["kind"] for j in children["items"])
    assert kinds.count("probe_run") == len(TRACES) and kinds.count("print") == 2 * len(TRACES)
    assert all(j["status"] == "succeeded" for j in children["items"])


def test_closed_loop_bad_input(client, meshes):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", meshes[0])}, headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[0].to_api(), headers=OP).json()
    real_machine = client.post("/api/v1/machines", json={"name": "r", "port": "socket://127.0.0.1:9"},
                               headers=OP).json()
    base = {"part_id": part["id"], "trace_ids": [trace["id"]], "machine_id": real_machine["id"]}
    no_truth = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {**base, "evaluate": True}},
                           headers=OP)
    assert no_truth.status_code == 422 and no_truth.json()["errors"][0]["loc"] == ["params", "evaluate"]
    wrong_trace = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {**base, "trace_ids": ["t_x"]}},
                              headers=OP)
    assert wrong_trace.status_code == 422 and "trace_ids" in wrong_trace.json()["errors"][0]["loc"]
    bad_probe = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        **base, "probe": {"method": "psychic"}}}, headers=OP)
    assert bad_probe.status_code == 422
