"""A linuxcnc:// machine through the service's API: register, connect, print, stop.

The same endpoints and the same ``print`` job as for serial machines; the controller is
Conforma's three-axis LinuxCNC simulator."""

from __future__ import annotations

import pytest

from tests.conftest import auth
from tests.jobs.test_jobs_api import wait_for

OP = auth("operator")
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "probe_command": "G38.2"}


@pytest.fixture
def lcnc_env(lcnc_xyz, monkeypatch):
    """The service finds the simulator's passwords and program directory in its environment."""
    monkeypatch.setenv("CONFORMA_LINUXCNC_CONNECTPW", lcnc_xyz.connect_pw)
    monkeypatch.setenv("CONFORMA_LINUXCNC_ENABLEPW", lcnc_xyz.enable_pw)
    monkeypatch.setenv("CONFORMA_LINUXCNC_PROGRAMS", str(lcnc_xyz.workdir / "programs"))
    return lcnc_xyz


def test_print_job_runs_a_program_on_linuxcnc(client, lcnc_env):
    body = {"name": "lcnc", "port": f"linuxcnc://127.0.0.1:{lcnc_env.port}?joints=3", "dialect": "linuxcnc",
            "profile": PROFILE}
    machine = client.post("/api/v1/machines", json=body, headers=OP)
    assert machine.status_code == 201, machine.text
    machine_id = machine.json()["id"]
    connected = client.post(f"/api/v1/machines/{machine_id}/connect", headers=OP).json()
    assert connected["state"] == "idle" and connected["firmware"].startswith("LinuxCNC")
    client.app.state.runtime.machines.get(machine_id).home()  # no home endpoint: LinuxCNC runs programs homed
    lines = ["G21", "G90", "G1 X0 Y0 Z2 F6000", "M64 P0"]
    lines += [f"G1 X{(i % 20) * 0.5:.2f} Y{(i // 20) * 0.5:.2f} F6000" for i in range(200)]
    lines += ["M65 P0", "G0 Z5"]
    program = client.post("/api/v1/programs", files={"file": ("p.ngc", ("\n".join(lines) + "\n").encode())},
                          headers=OP).json()
    job = client.post(f"/api/v1/machines/{machine_id}/print", json={"program_id": program["id"]}, headers=OP)
    assert job.status_code == 202
    done = wait_for(client, job.json()["id"], timeout=90)
    assert done["status"] == "succeeded", done["error"]
    assert done["result"]["executed"] == done["result"]["total"] == program["commands"]
    status = client.get(f"/api/v1/machines/{machine_id}", headers=OP).json()
    assert status["state"] == "idle" and status["position"] == pytest.approx([9.5, 4.5, 5.0], abs=1e-6)
    stop = client.post(f"/api/v1/machines/{machine_id}/stop", headers=OP)
    assert stop.status_code == 409  # nothing runs: stop sends nothing
    assert register_bad(client).status_code == 422


def register_bad(client):
    body = {"name": "x", "port": "linuxcnc://127.0.0.1:5007?programs=/etc", "dialect": "linuxcnc"}
    return client.post("/api/v1/machines", json=body, headers=OP)
