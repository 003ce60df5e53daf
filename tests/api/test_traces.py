"""Traces through the API on the S1 reference part: create, import, read, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from app.reference.s1 import nominal_height, s1_mesh, s1_traces
from tests.conftest import auth

OP = auth("operator")


@pytest.fixture(scope="module")
def s1_stl() -> bytes:
    return s1_mesh(grid_mm=0.5).export(file_type="stl")


@pytest.fixture
def part(client, s1_stl):
    response = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_stl)}, headers=OP)
    assert response.status_code == 201
    return response.json()


def test_nine_reference_traces_import_and_lie_on_the_top(client, part):
    body = [t.to_api() for t in s1_traces()]
    response = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=body, headers=OP)
    assert response.status_code == 201, response.text
    traces = response.json()["items"]
    assert [t["name"] for t in traces] == [t.name for t in s1_traces()]
    for trace, ref in zip(traces, s1_traces()):
        points = np.array(trace["nominal"]["points"])
        # draped onto the faceted top: within the tessellation error of the analytic surface
        assert np.abs(points[:, 2] - nominal_height(points[:, :2])).max() < 0.01
        assert trace["length_mm"] >= 32.0 - 1e-6
        assert trace["z_range"][0] == pytest.approx(points[:, 2].min(), abs=1e-6)
        assert trace["standoff_mm"] == ref.standoff_mm
    listed = client.get(f"/api/v1/parts/{part['id']}/traces", headers=OP).json()
    assert listed["total"] == 9
    one = client.get(f"/api/v1/traces/{traces[0]['id']}", headers=OP).json()
    assert one["geometry"] == traces[0]["geometry"]


@pytest.mark.parametrize(
    ("geometry", "loc_part"),
    [
        ({"type": "line", "start": [-10, 10], "end": [20, 10]}, "geometry"),
        ({"type": "line", "start": [10, 10], "end": [10, 10]}, "geometry"),
        ({"type": "nurbs", "degree": 2, "control_points": [[5, 5], [10, 8], [15, 5]], "knots": [0, 0, 1, 1]},
         "knots"),
        ({"type": "nurbs", "degree": 2, "control_points": [[5, 5], [10, 8], [15, 5]], "weights": [1, 0, 1]},
         "weights"),
        ({"type": "arc", "center": [20, 30], "radius": 0, "start_deg": 0, "end_deg": 90}, "radius"),
        ({"type": "polyline", "points": [[5, 5]]}, "points"),
    ],
)
def test_bad_traces_are_422_naming_the_field_and_store_nothing(client, part, geometry, loc_part):
    response = client.post(f"/api/v1/parts/{part['id']}/traces",
                           json={"name": "bad", "geometry": geometry}, headers=OP)
    assert response.status_code == 422, response.text
    body = response.json()
    assert any(loc_part in ".".join(map(str, e["loc"])) for e in body["errors"]), body
    assert client.get(f"/api/v1/parts/{part['id']}/traces", headers=OP).json()["total"] == 0


def test_off_part_message_gives_the_first_offending_coordinate(client, part):
    response = client.post(f"/api/v1/parts/{part['id']}/traces",
                           json={"name": "off", "geometry": {"type": "line", "start": [10, 10], "end": [10, 70]}},
                           headers=OP)
    assert response.status_code == 422
    # the S1 part spans x 0..60, y 0..40: the line leaves it at its y = 40 edge
    assert "leaves the part's surface at x=10.0, y=40.0" in response.json()["detail"]


def test_import_is_all_or_nothing(client, part):
    good = s1_traces()[0].to_api()
    bad = {"name": "bad", "geometry": {"type": "line", "start": [-10, 10], "end": [20, 10]}}
    response = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=[good, bad], headers=OP)
    assert response.status_code == 422
    assert response.json()["errors"][0]["loc"][0] == "1"
    assert client.get(f"/api/v1/parts/{part['id']}/traces", headers=OP).json()["total"] == 0


def test_trace_on_missing_part_is_404(client):
    response = client.post("/api/v1/parts/part_missing/traces", json=s1_traces()[0].to_api(), headers=OP)
    assert response.status_code == 404


def test_referenced_trace_and_part_cannot_be_deleted(client, part):
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[0].to_api(), headers=OP).json()
    job = client.post("/api/v1/jobs", json={"kind": "probe_plan", "params": {"trace_id": trace["id"]}}, headers=OP)
    assert job.status_code == 202
    assert client.delete(f"/api/v1/traces/{trace['id']}", headers=OP).status_code == 409
    assert client.delete(f"/api/v1/parts/{part['id']}", headers=OP).status_code == 409
    assert client.delete(f"/api/v1/parts/{part['id']}?force=true", headers=OP).status_code == 403
    assert client.delete(f"/api/v1/parts/{part['id']}?force=true", headers=auth("admin")).status_code == 204
    assert client.get(f"/api/v1/traces/{trace['id']}", headers=OP).status_code == 404
