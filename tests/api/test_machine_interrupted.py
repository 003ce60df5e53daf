"""An interrupted print holds its machine, and the machine record says so: the program
(where it stopped, of how many, where a resume starts when known), the job that holds the
machine and how to resume or abandon it; Print and Home are 409s naming that job."""

from __future__ import annotations

import pytest

from app.api.routes.machines import interrupted_program
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
PROGRAM = "G21\nG90\n" + "".join(f"G1 X{(i % 40) * 0.5:.2f} Y{(i // 40) * 0.5:.2f} F3000\n" for i in range(120))


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_an_interrupted_print_shows_on_its_machine_and_names_itself_in_every_409(client, dialect):
    profile = {"dispense_on": "M3 S1000", "dispense_off": "M5"} if dialect == "grbl" else {}
    machine = client.post("/api/v1/machines",
                          json={"name": "m", "port": "mock://", "dialect": dialect, "profile": profile,
                                                    "mock": {"faults": {"disconnect_at_line": 60}}}, headers=OP).json()
    program = client.post("/api/v1/programs", files={"file": ("p.gcode", PROGRAM.encode())}, headers=OP).json()
    job = client.post(f"/api/v1/machines/{machine['id']}/print", json={"program_id": program["id"]}, headers=OP).json()
    interrupted = wait_for(client, job["id"], states=("interrupted", "succeeded", "failed"), timeout=60)
    assert interrupted["status"] == "interrupted", interrupted
    executed, total = interrupted["program_state"]["executed"], interrupted["program_state"]["total"]
    assert total == 122 and 0 < executed < total

    record = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()
    assert record["held_by"] == job["id"]
    shown = record["program"]
    assert shown["state"] == "interrupted" and shown["job_id"] == job["id"] and shown["waits"] == "resume or abandon"
    assert shown["line"] == executed and shown["total"] == total
    if dialect == "grbl":   # a reset controller: the planner bound is known before reconnecting
        assert shown["resume_line"] is not None and shown["resume_line"] <= executed
    else:                   # a Marlin that may have kept running: the reconnect settles it by line numbers
        assert shown["resume_line"] is None
    assert f"command {executed} of {total}" in shown["message"]
    assert (f"/api/v1/jobs/{job['id']}/resume" in shown["message"]
            and f"/api/v1/jobs/{job['id']}/abandon" in shown["message"])

    again = client.post(f"/api/v1/machines/{machine['id']}/print", json={"program_id": program["id"]}, headers=OP)
    home = client.post(f"/api/v1/machines/{machine['id']}/home", headers=OP)
    for refused in (again, home):
        assert refused.status_code == 409, refused.text
        detail = refused.json()["detail"]
        assert job["id"] in detail and "interrupted" in detail and "resume" in detail and "abandon" in detail

    assert client.post(f"/api/v1/jobs/{job['id']}/abandon", headers=OP).status_code == 200
    record = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()
    assert record["held_by"] is None and record["program"] is None


def test_a_restarted_server_shows_the_interrupted_program_from_the_job_record():
    job = {"id": "job_1", "kind": "print", "status": "interrupted", "program_state": {"executed": 40, "total": 100}}
    shown = interrupted_program("mach_1", job, None)
    assert ((shown.state, shown.line, shown.total, shown.resume_line, shown.job_id)
            == ("interrupted", 40, 100, None, "job_1"))
    assert "command 40 of 100" in shown.message and "job_1" in shown.message


@pytest.mark.parametrize("dialect, why", [("marlin", "M106"), ("grbl", "switched its outputs off")])
def test_the_record_says_when_the_outputs_last_went_off_and_what_a_stop_left_on(client, dialect, why):
    profile = {"dispense_on": "M3 S1000", "dispense_off": "M5"} if dialect == "grbl" else {}
    machine = client.post("/api/v1/machines",
                          json={"name": "m", "port": "mock://", "dialect": dialect, "profile": profile},
                          headers=OP).json()
    connected = client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP).json()
    assert connected["outputs"] == {"safe_off": "connect", "sent": True, "why": None}
    assert client.post(f"/api/v1/machines/{machine['id']}/stop", headers=OP).status_code == 200
    stopped = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()
    assert stopped["outputs"]["safe_off"] == "emergency stop" and stopped["outputs"]["sent"] is False
    assert why in stopped["outputs"]["why"]
