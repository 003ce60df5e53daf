"""A mock machine with probe physics, created and driven through the API."""

from __future__ import annotations

import re

import pytest

from hardware.mock import MockPad, MockSphere, MockTool, get_world
from tests.conftest import auth

OP = auth("operator")
PHYSICS = {"stylus_radius_mm": 0.5, "pretravel_mm": 0.015, "drift_mm_per_min": 0.0,
           "tools": [{"offset_mm": [12.3, -4.1, -8.7], "outer_diameter_mm": 0.8}],
           "pad": {"centre_mm": [50, 10, 5], "size_mm": 20},
           "sphere": {"centre_mm": [100, 10, 12], "diameter_mm": 20}}


def _console(client, base: str, command: str) -> list[str]:
    response = client.post(f"{base}/command", json={"command": command}, headers=OP)
    assert response.status_code == 200, response.text
    return response.json()["reply"]


def test_machine_with_mock_physics_probes_with_a_ball(client):
    body = {"name": "physics", "port": "mock://", "dialect": "grbl",
            "profile": {"dispense_on": "M3 S1000", "dispense_off": "M5"}, "mock": {"physics": PHYSICS}}
    created = client.post("/api/v1/machines", json=body, headers=OP)
    assert created.status_code == 201, created.text
    machine = created.json()
    assert machine["mock"]["physics"]["stylus_radius_mm"] == 0.5
    base = f"/api/v1/machines/{machine['id']}"
    assert client.post(f"{base}/connect", headers=OP).status_code == 200
    world = get_world(machine["id"])
    assert world.stylus_radius_mm == 0.5 and world.pretravel_mm == 0.015
    assert world.tools == (MockTool((12.3, -4.1, -8.7), 0.8),)
    assert world.pad == MockPad((50.0, 10.0, 5.0), 20.0)
    assert world.sphere == MockSphere((100.0, 10.0, 12.0), 20.0)
    _console(client, base, "G1 X52 Y11 Z10 F3000")
    reply = _console(client, base, "G38.2 Z0 F100")
    prb = next(line for line in reply if line.startswith("[PRB:"))
    z = float(re.match(r"\[PRB:([-\d.]+),([-\d.]+),([-\d.]+):1\]", prb).group(3))
    assert z == pytest.approx(5.0 + 0.5 - 0.015, abs=0.0005)  # pad top + ball radius - pre-travel
    _console(client, base, "T1")
    assert world.active_tool == 1


@pytest.mark.parametrize("physics,field", [
    ({"stylus_radius_mm": -0.5}, "stylus_radius_mm"),
    ({"pretravel_mm": 50}, "pretravel_mm"),
    ({"tools": [{"offset_mm": [1, 2], "outer_diameter_mm": 1}]}, "offset_mm"),
    ({"tools": [{"offset_mm": [1, 2, 3], "outer_diameter_mm": 0}]}, "outer_diameter_mm"),
    ({"pad": {"centre_mm": [0, 0, 1e9], "size_mm": 10}}, "centre_mm"),
    ({"sphere": {"centre_mm": [0, 0, 0], "diameter_mm": -1}}, "diameter_mm"),
    ({"ball": 1}, "ball"),
])
def test_bad_mock_physics_is_422_naming_the_field(client, physics, field):
    body = {"name": "bad", "port": "mock://", "mock": {"physics": physics}}
    response = client.post("/api/v1/machines", json=body, headers=OP)
    assert response.status_code == 422, response.text
    assert field in response.text


def test_physics_url_options_are_checked_on_registration(client):
    body = {"name": "url", "port": "mock://?stylus_radius_mm=-1"}
    response = client.post("/api/v1/machines", json=body, headers=OP)
    assert response.status_code == 422, response.text
    assert response.json()["errors"][0]["loc"] == ["port", "stylus_radius_mm"]
