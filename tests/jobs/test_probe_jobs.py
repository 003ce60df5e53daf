"""probe_plan and reconstruct jobs through the API on the S1 reference part."""

from __future__ import annotations

import numpy as np
import pytest

from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=0.5).export(file_type="stl")


@pytest.fixture
def trace(client, s1_stl):
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP).json()
    return client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[6].to_api(), headers=OP).json()


@pytest.mark.parametrize("method", ["adaptive", "uniform", "deviation", "kriging"])
def test_probe_plan_writes_a_safe_program(client, trace, method):
    params = {"trace_id": trace["id"], "method": method}
    if method == "uniform":
        params["count"] = 12
    job = wait_for(client, submit(client, "probe_plan", params).json()["id"])
    assert job["status"] == "succeeded", job["error"]
    result = job["result"]
    assert result["count"] == len(result["points"]) == len(result["records"]) >= 4
    if method == "uniform":
        assert result["count"] == 12
    gcode = client.get(job["artifacts"][0]["url"], headers=OP).text
    assert gcode.count("G38.2") == result["count"] and "G21" in gcode and "G90" in gcode
    meta = job["artifacts"][0]["meta"]
    from hardware.protocol import commands_sha256

    assert meta["commands_sha256"] == commands_sha256(gcode.splitlines()).sha256
    # every probe target lies on the nominal trace, in order along it
    from app.geometry.traces import as_trace_polyline

    path = as_trace_polyline(np.array(trace["nominal"]["points"]))
    points = np.array(result["points"])
    assert np.all(np.diff(result["s_mm"]) > 0)
    assert np.allclose(path.at(np.array(result["s_mm"])), points, atol=1e-6)


@pytest.mark.parametrize("method", ["deviation", "kriging"])
def test_reconstruct_from_points_recovers_the_as_made_deviation(client, trace, method):
    plan = wait_for(client, submit(client, "probe_plan", {"trace_id": trace["id"], "method": method}).json()["id"])
    truth = as_made(seed=3, amplitude_mm=0.15)
    xy = np.array(plan["result"]["points"])[:, :2]
    measured = np.column_stack([xy, truth.true_height(xy)])
    job = wait_for(client, submit(client, "reconstruct", {"trace_id": trace["id"], "points": measured.tolist(),
                                                          "method": method}).json()["id"])
    assert job["status"] == "succeeded", job["error"]
    samples = np.array(job["result"]["deviation"]["samples"])
    nominal_z = np.array(plan["result"]["points"])[:, 2]
    assert np.allclose(samples[:, 1], measured[:, 2] - nominal_z, atol=0.01)  # mesh tessellation only
    assert job["result"]["deviation"]["max_mm"] == pytest.approx(np.abs(samples[:, 1]).max())
    curve = job["result"]["curve"]
    assert len(curve["knots"]) == len(curve["control_points"]) + curve["degree"] + 1


@pytest.mark.parametrize(
    ("case", "needle"),
    [("three", "needs 4"), ("one_station_repeated", "needs 4"), ("far_away", "from the trace")],
)
def test_bad_measurements_are_refused_at_submission(client, trace, case, needle):
    nominal = np.array(trace["nominal"]["points"])
    points = {
        "three": nominal[[0, 40, 80]],
        "one_station_repeated": np.repeat(nominal[[40]], 5, axis=0),
        "far_away": nominal[[0, 40, 80, 120, 160]] + [30.0, 0.0, 0.0],
    }[case]
    response = submit(client, "reconstruct", {"trace_id": trace["id"], "points": points.tolist()})
    assert response.status_code == 422, response.text
    assert needle in response.json()["detail"]
    assert client.get("/api/v1/jobs?kind=reconstruct", headers=OP).json()["total"] == 0


def test_nan_points_and_missing_sources_are_422(client, trace):
    nan = client.post("/api/v1/jobs", content=b'{"kind": "reconstruct", "params": {"trace_id": "%s", '
                      b'"points": [[1, 2, NaN]]}}' % trace["id"].encode(),
                      headers={**OP, "content-type": "application/json"})
    assert nan.status_code == 422
    neither = submit(client, "reconstruct", {"trace_id": trace["id"]})
    assert neither.status_code == 422 and "exactly one" in neither.json()["detail"]
    missing = submit(client, "probe_plan", {"trace_id": "trace_nope"})
    assert missing.status_code == 422 and missing.json()["errors"][0]["loc"] == ["params", "trace_id"]
