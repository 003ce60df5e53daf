"""The operator sees what a resume will do before confirming it (``GET /jobs/{id}/resume``):
the command it resumes at, the basis, the commands and moves that may run again and that
none is skipped; the confirmed resume then continues exactly there (grbl mock, reset)."""

from __future__ import annotations

from hardware.mock import get_world
from hardware.protocol import normalized_commands
from tests.conftest import auth
from tests.jobs.test_jobs_api import wait_for
from tests.jobs.test_machine_safety import program, start_print, upload

OP = auth("operator")


def test_the_resume_preview_states_line_basis_and_repeats_and_the_resume_keeps_to_it(client):
    machine = client.post("/api/v1/machines", json={"name": "g", "port": "mock://?homing=1", "dialect": "grbl",
                                                    "mock": {"time_scale": 1.0, "faults": {"reset_at_line": 120}}},
                          headers=OP).json()  # real time: the repeats are bounded in real seconds
    base = f"/api/v1/machines/{machine['id']}"
    assert client.post(f"{base}/connect", headers=OP).json()["controller"]["state"] == "Alarm"  # boots locked
    assert client.post(f"{base}/home", headers=OP).json()["controller"]["state"] == "Idle"
    text = program(240)
    job = start_print(client, machine, upload(client, text)).json()
    interrupted = wait_for(client, job["id"], states=("interrupted", "succeeded", "failed"), timeout=60)
    assert interrupted["status"] == "interrupted", interrupted
    ran = len(get_world(machine["id"]).transcript.commands)  # the commands whose motion completed
    preview = client.get(f"/api/v1/jobs/{job['id']}/resume", headers=OP)
    assert preview.status_code == 200, preview.text
    shown = preview.json()
    assert shown["skipped"] == 0 and shown["start"] <= ran and shown["line"] == shown["start"] + 1
    assert shown["basis"] in ("planner bound", "reported position", "position") and shown["total"] == 242
    assert ran - shown["start"] <= shown["repeats"] and "none is skipped" in shown["summary"], shown
    assert f"command {shown['line']}" in shown["summary"]
    assert client.post(f"/api/v1/jobs/{job['id']}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, job["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    assert done["result"]["start_line"] == shown["start"]  # it resumed where the preview said
    assert done["result"]["resume_location"]["summary"] == shown["summary"]
    commands = normalized_commands(text.splitlines())
    executed = get_world(machine["id"]).transcript.commands
    assert executed[-(len(commands) - shown["start"]):] == commands[shown["start"]:]  # the rest ran, once
    assert client.get(f"/api/v1/jobs/{job['id']}/resume", headers=OP).status_code == 409  # nothing to resume
