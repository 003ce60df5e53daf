"""A program that leaves a machine's travel (profile.volume_mm) is refused at print, with the
axis and the amount."""

from __future__ import annotations

from tests.api.test_machines import program_text, upload_program
from tests.conftest import auth

OP = auth("operator")


def test_print_refuses_a_program_beyond_the_machine_travel(client):
    volume = {"x": [0, 12], "y": [0, 100], "z": [0, 50]}
    machine = client.post("/api/v1/machines", json={"name": "small", "port": "mock://small",
                                                    "profile": {"volume_mm": volume}}, headers=OP)
    assert machine.status_code == 201, machine.text
    assert machine.json()["profile"]["volume_mm"] == volume
    program = upload_program(client, program_text()).json()          # X runs 10.0 ... 14.9
    response = client.post(f"/api/v1/machines/{machine.json()['id']}/print", json={"program_id": program["id"]},
                           headers=OP)
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert "on X" in detail and "2.9000 mm beyond the limit 12" in detail
    bad = client.post("/api/v1/machines", json={"name": "bad", "port": "mock://bad",
                                                "profile": {"volume_mm": {"x": [5, 1], "y": [0, 1], "z": [0, 1]}}},
                      headers=OP)
    assert bad.status_code == 422
