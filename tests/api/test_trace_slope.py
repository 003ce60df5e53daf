"""The slope policy in the trace-create path, on a sphere: reported, warned, refused."""

from __future__ import annotations

import math

import pytest
import trimesh

from tests.conftest import auth

OP = auth("operator")
R = 20.0


@pytest.fixture
def sphere_part(client) -> str:
    stl = trimesh.creation.icosphere(subdivisions=5, radius=R).export(file_type="stl")
    response = client.post("/api/v1/parts", files={"file": ("sphere.stl", stl)}, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def line(x_end: float, **extra) -> dict:
    return {"name": f"to {x_end}", "geometry": {"type": "line", "start": [0, 0], "end": [x_end, 0]}, **extra}


def test_slope_reported_warned_and_refused_on_a_sphere(client, sphere_part):
    url = f"/api/v1/parts/{sphere_part}/traces"
    gentle = client.post(url, json=line(5.0), headers=OP)
    assert gentle.status_code == 201, gentle.text
    slope = gentle.json()["nominal"]["slope"]
    assert slope["max_slope_deg"] == pytest.approx(math.degrees(math.asin(5 / R)), abs=2.0)
    assert slope["warnings"] == []

    steep = client.post(url, json=line(14.0), headers=OP)          # 44 deg: accepted with a warning
    assert steep.status_code == 201
    assert "steep" in steep.json()["nominal"]["slope"]["warnings"][0]
    assert client.get(f"/api/v1/traces/{steep.json()['id']}", headers=OP).json()["nominal"]["slope"]["warnings"]

    refused = client.post(url, json=line(19.0), headers=OP)        # 72 deg: beyond 60 for a vertical nozzle
    assert refused.status_code == 422
    problem = refused.json()
    assert "five_axis" in problem["detail"] and problem["errors"][0]["loc"][-1] == "geometry"
    assert client.get(url, headers=OP).json()["total"] == 2         # nothing stored for the refused one

    allowed = client.post(url, json=line(19.0, slope_max_deg=80, slope_warn_deg=45), headers=OP)
    assert allowed.status_code == 201 and allowed.json()["nominal"]["slope"]["warnings"]
