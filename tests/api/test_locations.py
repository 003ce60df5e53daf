"""Every POST that creates something answers with a ``Location`` that reads it back, also
when an idempotent retry replays the answer."""

from __future__ import annotations

from app.reference.s1 import s1_mesh
from tests.api.test_machines import program_text, register, upload_program
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


def _reads_back(client, response, key="id"):  # type: ignore[no-untyped-def]
    assert response.status_code in (201, 202), response.text
    location = response.headers["location"]
    again = client.get(location, headers=OP)
    assert again.status_code == 200 and again.json()[key] == response.json()[key]
    return location


def test_parts_programs_machines_and_prints_say_where_they_are(client):
    stl = s1_mesh(grid_mm=2.0).export(file_type="stl")
    first = client.post("/api/v1/parts", files={"file": ("s1.stl", stl)}, headers={**OP, "Idempotency-Key": "p-1"})
    location = _reads_back(client, first)
    replay = client.post("/api/v1/parts", files={"file": ("s1.stl", stl)}, headers={**OP, "Idempotency-Key": "p-1"})
    assert replay.headers["location"] == location and replay.json()["id"] == first.json()["id"]
    program = upload_program(client, program_text(5))
    _reads_back(client, program)
    machine = register(client)
    _reads_back(client, machine)
    client.post(f"{machine.headers['location']}/connect", headers=OP)
    printed = client.post(f"{machine.headers['location']}/print", json={"program_id": program.json()["id"]},
                          headers=OP)
    _reads_back(client, printed)
    assert wait_for(client, printed.json()["id"])["status"] == "succeeded"
