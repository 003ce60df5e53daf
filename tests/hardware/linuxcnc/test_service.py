"""A linuxcnc:// machine through the service's API: register, connect, print, probe_run, stop.

The same endpoints and the same ``print`` job as for serial machines; the controller is
Conforma's three-axis LinuxCNC simulator."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from app.reference.s1 import s1_mesh, s1_traces
from hardware.linuxcnc.hal_command import hal_command
from hardware.machine_state import InterruptedProgram
from tests.conftest import auth
from tests.hardware.linuxcnc.conftest import SURFACE_SLOPE_X, SURFACE_Z, wait_until
from tests.helpers.jobs import wait_for

OP = auth("operator")
PROFILE = {"dispense_on": "M64 P0", "dispense_off": "M65 P0", "probe_command": "G38.2"}


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
    # a stop always reaches the controller, idle or not: LinuxCNC is then in e-stop
    assert stop.status_code == 200 and stop.json()["stop_sent"] is True, stop.text
    assert client.get(f"/api/v1/machines/{machine_id}", headers=OP).json()["state"] == "error"
    assert register_bad(client).status_code == 422


def test_a_print_whose_link_drops_shows_where_linuxcnc_stopped_and_resumes_from_its_record(client, lcnc_env):
    """The service reads a LinuxCNC machine's interrupted program as it reads a serial one's:
    the machine's record (``InterruptedProgram``) gives the job its count, the machine record
    shows it live with the resume line it tells, and the operator's resume starts there and
    ends where the uninterrupted program ends."""
    body = {"name": "lcnc", "port": f"linuxcnc://127.0.0.1:{lcnc_env.port}?joints=3", "dialect": "linuxcnc",
            "profile": PROFILE}
    machine_id = client.post("/api/v1/machines", json=body, headers=OP).json()["id"]
    client.post(f"/api/v1/machines/{machine_id}/connect", headers=OP)
    live = client.app.state.runtime.machines.get(machine_id)
    live.home()
    lines = ["G21", "G90", "G1 X0 Y0 Z2 F6000"]  # then 1 mm moves at 600 mm/min: 0.1 s each, rows back 0.9 s
    lines += [f"G1 X{i % 10:.1f} Y{i // 10:.1f} F600" for i in range(60)] + ["G0 Z5"]
    program = client.post("/api/v1/programs", files={"file": ("p.ngc", ("\n".join(lines) + "\n").encode())},
                          headers=OP).json()
    job_id = client.post(f"/api/v1/machines/{machine_id}/print", json={"program_id": program["id"]},
                         headers=OP).json()["id"]
    assert wait_until(lambda: live.state == "printing" and live.progress[0] >= 10, 60.0)
    live.link.sever()
    job = wait_for(client, job_id, states=("interrupted", "succeeded", "failed"), timeout=60)
    assert job["status"] == "interrupted", job["error"]
    gap = live.interrupted_program
    assert isinstance(gap, InterruptedProgram) and gap.total == len(lines) and 10 <= gap.acked_index < len(lines)
    assert job["program_state"]["executed"] == gap.acked_index and job["program_state"]["total"] == len(lines)
    shown = client.get(f"/api/v1/machines/{machine_id}", headers=OP).json()["program"]
    assert (shown["state"], shown["job_id"], shown["line"], shown["total"], shown["resume_line"]) == \
        ("interrupted", job_id, gap.acked_index, len(lines), gap.acked_index)
    preview = client.get(f"/api/v1/jobs/{job_id}/resume", headers=OP).json()
    assert preview["start"] == gap.acked_index and preview["skipped"] == 0
    assert client.post(f"/api/v1/jobs/{job_id}/resume", json={"confirm": True}, headers=OP).status_code == 202
    done = wait_for(client, job_id, timeout=120)
    assert done["status"] == "succeeded", done["error"]
    assert done["result"]["executed"] == done["result"]["total"] == len(lines)
    assert done["program_state"]["resumed_from"] == gap.acked_index and live.interrupted_program is None
    assert done["program_state"]["resume_location"]["start"] == gap.acked_index
    status = client.get(f"/api/v1/machines/{machine_id}", headers=OP).json()
    assert status["program"] is None and status["position"] == pytest.approx([9.0, 5.0, 5.0], abs=1e-6)


def register_bad(client):
    body = {"name": "x", "port": "linuxcnc://127.0.0.1:5007?programs=/etc", "dialect": "linuxcnc"}
    return client.post("/api/v1/machines", json=body, headers=OP)


def _halcmd(sim, *args: str) -> str:  # type: ignore[no-untyped-def]
    return subprocess.run(hal_command(["halcmd", *args], sim.hal_env), capture_output=True, text=True, timeout=10,
                          check=True, env=sim.hal_env).stdout.strip()


def test_probe_run_job_touches_the_simulated_surface(client, lcnc_env):
    """A probe plan of a reference trace, run by the probe_run job on LinuxCNC: every touch
    lands on the simulator's probe plane z = z0 + 0.01 x (z0 moved under the trace via HAL)."""
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=0.5).export(file_type="stl"))},
                       headers=OP).json()
    trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[3].to_api(), headers=OP).json()
    plan = wait_for(client, client.post("/api/v1/jobs", json={"kind": "probe_plan", "params": {
        "trace_id": trace["id"], "method": "uniform", "count": 5}}, headers=OP).json()["id"])
    assert plan["status"] == "succeeded", plan["error"]
    records = plan["result"]["records"]
    nominal = np.array([r["nominal"] for r in records])
    z0 = float(np.median(nominal[:, 2] - SURFACE_SLOPE_X * nominal[:, 0]))
    plane = z0 + SURFACE_SLOPE_X * nominal[:, 0]
    assert all(r["target_z_mm"] < z < r["safe_z_mm"] for r, z in zip(records, plane))  # reachable
    _halcmd(lcnc_env, "setp", "conforma-surface.offset", repr(z0))
    try:
        body = {"name": "lcnc", "port": f"linuxcnc://127.0.0.1:{lcnc_env.port}?joints=3", "dialect": "linuxcnc",
                "profile": PROFILE}
        machine_id = client.post("/api/v1/machines", json=body, headers=OP).json()["id"]
        client.post(f"/api/v1/machines/{machine_id}/connect", headers=OP)
        client.app.state.runtime.machines.get(machine_id).home()
        run = client.post("/api/v1/jobs", json={"kind": "probe_run", "params": {
            "plan_job_id": plan["id"], "machine_id": machine_id, "probe_feed_mm_min": 200}}, headers=OP)
        assert run.status_code == 202, run.text
        done = wait_for(client, run.json()["id"], timeout=120)
    finally:
        _halcmd(lcnc_env, "setp", "conforma-surface.offset", repr(SURFACE_Z))
    assert done["status"] == "succeeded", done["error"]
    measured = np.array([p["measured"] for p in done["result"]["points"]])
    assert measured[:, :2] == pytest.approx(nominal[:, :2], abs=1e-4)
    # the trip is seen at most two 1 ms servo periods late (sampling + the sim's one-period
    # feedback lag): 6.7 um at 200 mm/min, always below the surface
    late = 2 * 200 / 60 * 0.001
    assert np.all(measured[:, 2] <= plane + 1e-4) and np.all(measured[:, 2] >= plane - late - 1e-4)
