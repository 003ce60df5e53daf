"""The ``register`` job through the API on the mock, and the placement it hands on.

The mock places its true part (here the nominal S1 part itself, so the top carries no
machining error) with a known rigid placement about the machine origin and probes along
-Z with 1 um noise; the job must recover that placement within 3 sigma of the
uncertainty it reports.  probe_plan / reconstruct with the registration work on the
trace moved into machine coordinates (checked against the placement applied
independently).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.placement import Placement, apply_placement
from app.geometry.traces import as_trace_polyline
from app.jobs.results.models import RegisterResult, StoredResultError
from app.reference.s1 import s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
TRUE = {"dx": 0.2, "dy": -0.15, "dz": 0.03, "rz_deg": 0.3}


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=0.5).export(file_type="stl")


def mock_machine(client, true_part_id: str, placement: dict, name: str = "sim") -> dict:
    return client.post("/api/v1/machines", json={
        "name": name, "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": true_part_id, "placement": placement, "probe_noise_mm": 0.001,
                 "faults": {"seed": 3}}}, headers=OP).json()


@pytest.fixture
def registered(client, s1_stl):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()
    machine = mock_machine(client, part["id"], TRUE)
    response = submit(client, "register", {"part_id": part["id"], "machine_id": machine["id"]})
    assert response.status_code == 202, response.text
    job = wait_for(client, response.json()["id"], timeout=60)
    return part, machine, job


def test_register_recovers_the_mock_placement_within_three_sigma(registered):
    _, _, job = registered
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    est, std = result["placement"], result["std"]
    assert est["pivot"] == [0.0, 0.0] and result["unobservable"] == []
    for key in ("dx", "dy", "dz"):
        assert abs(est[key] - TRUE[key]) <= 3 * std[f"{key}_mm"], (key, est[key], std)
        assert std[f"{key}_mm"] < 0.005
    assert abs(est["rz_deg"] - TRUE["rz_deg"]) <= 3 * std["rz_deg"] and std["rz_deg"] < 0.005
    # the covariance is the reported std squared on its diagonal, symmetric, positive definite
    cov = np.array(result["covariance"]["matrix"])
    labels = result["covariance"]["parameters"]
    assert labels == ["dx_mm", "dy_mm", "dz_mm", "rz_deg"]
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [std[k] for k in labels], rtol=1e-9)
    np.testing.assert_allclose(cov, cov.T, atol=1e-18)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert set(result["plan"]["predicted_std"]) == set(labels)
    # every touch recorded: side faces by several -Z touches each, heights by one
    touches = result["touches"]
    assert sum(t["touches"] for t in touches) == result["probe_count"]
    sides = [t for t in touches if t["face"] in ("+x", "-x", "+y", "-y")]
    assert {t["face"][1] for t in sides} == {"x", "y"} and all(t["touches"] > 5 for t in sides)
    # each found wall point lies on the truly placed wall (1 um bisection + 1 um noise)
    truth = Placement.from_deg(**TRUE)
    for t in sides:
        nominal_wall = np.dot(t["normal"], t["nominal"])
        in_part = np.linalg.inv(truth.matrix()) @ np.array([*t["measured"], 1.0])
        assert abs(np.dot(t["normal"], in_part[:3]) - nominal_wall) < 0.002
    # the stored result reads back through the register model, by attribute
    typed = RegisterResult.of_record(job)
    assert typed.placement == est and typed.probe_count == result["probe_count"] and typed.mode == "edges"
    assert typed.model_dump(exclude_unset=True) == result
    assert typed.echo() == {k: result[k] for k in ("placement", "std", "covariance", "unobservable", "probe_count")}
    for key in ("placement", "std", "probe_count"):
        with pytest.raises(StoredResultError) as caught:
            RegisterResult.of_record({**job, "result": {k: v for k, v in result.items() if k != key}})
        assert caught.value.field == f"result.{key}"


def test_probe_plan_and_reconstruct_use_the_registration(client, registered):
    part, _, job = registered
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[3].to_api(), headers=OP).json()
    est = job["result"]["placement"]
    placement = Placement.from_deg(est["dx"], est["dy"], est["dz"], est["rz_deg"], tuple(est["pivot"]))
    path = as_trace_polyline(np.array(trace["nominal"]["points"]))
    plans = {}
    for how in ("registration_job_id", "placement", None):
        extra = {"registration_job_id": job["id"]} if how == "registration_job_id" else (
            {"placement": est} if how == "placement" else {})
        plans[how] = wait_for(client, submit(client, "probe_plan", {
            "trace_id": trace["id"], "method": "uniform", "count": 8, **extra}).json()["id"])
        assert plans[how]["status"] == "succeeded", plans[how]["error"]
    s_mm = np.array(plans[None]["result"]["s_mm"])
    unplaced = np.array(plans[None]["result"]["points"])
    np.testing.assert_allclose(unplaced, path.at(s_mm), atol=1e-9)  # unchanged without a placement
    assert "placement" not in plans[None]["result"]
    for how in ("registration_job_id", "placement"):
        placed = np.array(plans[how]["result"]["points"])
        np.testing.assert_allclose(placed, apply_placement(path.at(s_mm), placement), atol=1e-9)
        assert plans[how]["result"]["placement"]["rz_deg"] == pytest.approx(est["rz_deg"])
    shift = np.linalg.norm(placed[:, :2] - unplaced[:, :2], axis=1)
    assert shift.min() > 0.05 and shift.max() > 0.15  # the registration really moved the probes
    # measured points in machine coordinates: near the placed trace, far from the unplaced one
    measured = placed + np.array([0.0, 0.0, 0.01])
    rebuilt = wait_for(client, submit(client, "reconstruct", {
        "trace_id": trace["id"], "points": measured.tolist(), "registration_job_id": job["id"]}).json()["id"])
    assert rebuilt["status"] == "succeeded", rebuilt["error"]
    assert rebuilt["result"]["deviation"]["max_mm"] == pytest.approx(0.01, abs=1e-6)
    both = submit(client, "probe_plan", {"trace_id": trace["id"], "placement": est, "registration_job_id": job["id"]})
    assert both.status_code == 422 and "at most one" in both.json()["detail"]
    not_register = submit(client, "probe_plan", {"trace_id": trace["id"],
                                                 "registration_job_id": plans[None]["id"]})
    assert not_register.status_code == 422
    assert not_register.json()["errors"][0]["loc"] == ["params", "registration_job_id"]


def test_flat_top_z_only_reports_what_it_cannot_see(client):
    box = trimesh.creation.box(extents=(60.0, 40.0, 10.0))
    box.apply_translation([30.0, 20.0, 5.0])
    part = client.post("/api/v1/parts", files={"file": ("box.stl", box.export(file_type="stl"))},
                       headers=OP).json()
    machine = mock_machine(client, part["id"], {"dx": 0.3, "dz": 0.05, "rz_deg": 0.2}, name="box")
    job = wait_for(client, submit(client, "register", {"part_id": part["id"], "machine_id": machine["id"],
                                                       "mode": "z_only", "count": 5}).json()["id"], timeout=60)
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    assert set(result["unobservable"]) >= {"dx", "dy"} and result["probe_count"] == 5
    assert abs(result["placement"]["dz"] - 0.05) <= 3 * result["std"]["dz_mm"]
    assert result["placement"]["dx"] == 0.0  # held, not guessed


@pytest.mark.parametrize(("params", "loc"), [
    ({"mode": "psychic"}, ["params", "mode"]),
    ({"sigma_mm": 0}, ["params", "sigma_mm"]),
    ({"pivot_xy": [1.0]}, ["params", "pivot_xy"]),
    ({"search_mm": 3.0}, ["params"]),  # must stay below margin_mm
    ({"part_id": "part_nope"}, ["params", "part_id"]),
])
def test_bad_register_parameters_are_422_and_store_nothing(client, s1_stl, params, loc):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()
    machine = mock_machine(client, part["id"], {})
    response = submit(client, "register", {"part_id": part["id"], "machine_id": machine["id"], **params})
    assert response.status_code == 422, response.text
    assert response.json()["errors"][0]["loc"][:len(loc)] == loc
    assert client.get("/api/v1/jobs?kind=register", headers=OP).json()["total"] == 0

