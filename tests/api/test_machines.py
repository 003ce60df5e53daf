"""Machines and programs through the API, against the mock firmware behind mock://."""

from __future__ import annotations

import numpy as np
import pytest

from app.reference.s1 import as_made, s1_mesh, s1_traces
from hardware.protocol import commands_sha256
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


def program_text(n: int = 400) -> str:
    lines = ["; test program", "G21", "G90", "M106 S255"]  # marlin's default dispenser commands
    for i in range(n):
        lines.append(f"G1 X{10 + (i % 50) * 0.1:.3f} Y{20 + (i // 50) * 0.1:.3f} Z1.000 F600 ; move {i}")
    lines += ["M107", "G0 Z5"]
    return "\n".join(lines) + "\n"


def register(client, port="mock://", dialect="marlin", **mock):
    body = {"name": "bench", "port": port, "dialect": dialect}
    if mock:
        body["mock"] = mock
    return client.post("/api/v1/machines", json=body, headers=OP)


def upload_program(client, text: str, name="prog.gcode"):
    return client.post("/api/v1/programs", files={"file": (name, text.encode())}, headers=OP)


def test_program_upload_reports_the_command_digest(client):
    text = program_text(10)
    program = upload_program(client, text)
    assert program.status_code == 201
    body = program.json()
    digest = commands_sha256(text.splitlines())
    assert body["commands"] == digest.count == 15 and body["commands_sha256"] == digest.sha256
    assert body["bounds"][0][:2] == [10.0, 20.0]
    assert client.get(f"/api/v1/programs/{body['id']}/file", headers=OP).text == text


@pytest.mark.parametrize(("data", "needle"), [(b"\xff\xfe\x00binary", "UTF-8"), (b"hello world\nthis is prose\n",
                                                                                "not G-code"), (b"; only a comment\n",
                                                                                               "no G-code")])
def test_non_gcode_programs_are_refused(client, data, needle):
    response = client.post("/api/v1/programs", files={"file": ("x.gcode", data)}, headers=OP)
    assert response.status_code == 422 and needle in response.json()["detail"]


@pytest.mark.parametrize("faults", [{}, {"checksum_rate": 0.01, "drop_ok_rate": 0.01, "duplicate_ok_rate": 0.01,
                                         "resend_rate": 0.01, "garbage_rate": 0.01, "busy_rate": 0.01, "seed": 4}])
def test_print_executes_every_command_exactly_once(client, faults):
    machine = register(client, faults=faults).json()
    assert machine["state"] == "disconnected"
    connected = client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP).json()
    assert connected["state"] == "idle" and connected["firmware"]
    program = upload_program(client, program_text()).json()
    job = client.post(f"/api/v1/machines/{machine['id']}/print", json={"program_id": program["id"]}, headers=OP)
    assert job.status_code == 202
    done = wait_for(client, job.json()["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    status = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()
    # the connect's safe_off, the program's safe_off (every program starts with its outputs off),
    # then every command of the program exactly once
    safe = [status["profile"]["dispense_off"], *status["profile"]["outputs_off"]]
    assert status["mock"]["executed_commands"] == 2 * len(safe) + program["commands"]
    assert status["mock"]["executed_sha256"] == commands_sha256([*safe, *safe, *program_text().splitlines()]).sha256
    assert status["mock"]["deposited_moves"] == 400  # every G1 between M106 and M107
    assert status["state"] == "idle"


def test_machine_bad_input_and_safe_states(client):
    assert register(client, dialect="fanuc").status_code == 422
    bad_option = register(client, port="mock://?checksum_rate=2")
    assert bad_option.status_code == 422 and "checksum_rate" in bad_option.json()["detail"]
    assert register(client, port="not a port").status_code == 422
    assert register(client, port="socket://127.0.0.1:9", true_part_id=None).status_code == 422  # mock on real port
    unreachable = client.post("/api/v1/machines", json={"name": "x", "port": "socket://127.0.0.1:9"}, headers=OP).json()
    response = client.post(f"/api/v1/machines/{unreachable['id']}/connect", headers=OP)
    assert response.status_code == 503
    machine = register(client).json()
    assert client.post(f"/api/v1/machines/{machine['id']}/stop", headers=OP).status_code == 409  # not connected
    client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP)
    idle_stop = client.post(f"/api/v1/machines/{machine['id']}/stop", headers=OP)  # sent even when idle
    assert idle_stop.status_code == 200 and idle_stop.json()["stop_sent"] is True
    assert client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()["state"] == "error"  # M112 halts
    assert client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP).json()["state"] == "idle"
    job = client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0, "artifact": True}},
                      headers=OP).json()
    wait_for(client, job["id"])
    not_gcode = client.post(f"/api/v1/machines/{machine['id']}/print",
                            json={"job_id": job["id"], "artifact": "hello.txt"}, headers=OP)
    assert not_gcode.status_code == 422 and "not G-code" in not_gcode.json()["detail"]


def test_probe_run_measures_the_true_part_within_three_sigma(client):
    truth = as_made(seed=2, amplitude_mm=0.15)
    true_mesh = truth.mesh(grid_mm=0.5)
    nominal = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=0.5).export(file_type="stl"))},
                          headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("true.stl", true_mesh.export(file_type="stl"))},
                       headers=OP).json()
    trace = client.post(f"/api/v1/parts/{nominal['id']}/traces", json=s1_traces()[3].to_api(), headers=OP).json()
    sigma = 0.001
    machine = register(client, dialect="grbl", true_part_id=real["id"], probe_noise_mm=sigma).json()
    plan = wait_for(client, client.post("/api/v1/jobs", json={"kind": "probe_plan", "params": {
        "trace_id": trace["id"], "method": "uniform", "count": 10}}, headers=OP).json()["id"])
    run = client.post("/api/v1/jobs", json={"kind": "probe_run", "params": {
        "plan_job_id": plan["id"], "machine_id": machine["id"]}}, headers=OP)
    assert run.status_code == 202, run.text
    done = wait_for(client, run.json()["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    measured = np.array([p["measured"] for p in done["result"]["points"]])
    import trimesh

    hits, _, _ = trimesh.ray.ray_pyembree.RayMeshIntersector(true_mesh).intersects_location(
        np.column_stack([measured[:, :2], np.full(len(measured), 100.0)]), np.tile([0, 0, -1.0], (len(measured), 1)))
    truth_z = np.array([hits[np.argmin(np.linalg.norm(hits[:, :2] - p[:2], axis=1))][2] for p in measured])
    assert np.abs(measured[:, 2] - truth_z).max() < 3 * sigma + 1e-4
    assert done["result"]["stats"]["count"] == 10


@pytest.mark.parametrize("dialect, port, on, off", [("marlin", "mock://", "M106 S255", "M107"),
                                                    ("grbl", "mock://", "M8", "M9"),
                                                    ("linuxcnc", "linuxcnc://127.0.0.1:5007", "M64 P0", "M65 P0")])
def test_a_profile_without_a_dispenser_gets_its_dialects(client, dialect, port, on, off):
    machine = register(client, port=port, dialect=dialect).json()
    assert (machine["profile"]["dispense_on"], machine["profile"]["dispense_off"]) == (on, off)
    named = client.post("/api/v1/machines", json={"name": "own", "port": "mock://", "dialect": dialect,
                                                  "profile": {"dispense_on": "M7", "dispense_off": "M9"}},
                        headers=OP).json()
    assert (named["profile"]["dispense_on"], named["profile"]["dispense_off"]) == ("M7", "M9")


def test_a_grbl_registered_without_a_profile_switches_its_dispenser_off_on_connect(client):
    machine = register(client, dialect="grbl").json()
    connected = client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP)
    assert connected.status_code == 200, connected.text
    outputs = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()["outputs"]
    assert outputs["sent"] is True and outputs["why"] is None  # M5 is grbl's: nothing skipped as unknown
    client.post(f"/api/v1/machines/{machine['id']}/disconnect", headers=OP)
