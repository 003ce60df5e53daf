"""A stop stops the process too: after an emergency stop mid-print and a reconnect every
process output is off by LinuxCNC's own status (``linuxcnc.stat``), and a travel-only
program dispenses nothing (the dispense output ``motion.digital-out-00`` sampled from HAL
the whole time).  The host's own part (``safe_off`` by MDI on connect and disconnect) is
tested apart from the controller's ``ON_ABORT_COMMAND``."""

from __future__ import annotations

import threading
import time

import pytest

from hardware.errors import HardwareError
from hardware.machine_types import MachineProfile
from tests.hardware.linuxcnc.conftest import PROFILE, wait_until

ALL_OFF = {"dout": [0, 0, 0, 0], "spindle": 0, "mist": 0, "flood": 0}
OUTPUTS = ["motion.digital-out-00", "motion.digital-out-01", "motion.digital-out-02", "motion.digital-out-03"]


def _off(outputs: dict) -> dict:
    return {k: v for k, v in outputs.items() if k != "task_state"}


def test_stop_mid_print_and_reconnect_leave_every_output_off(lcnc_xyz):
    machine = lcnc_xyz.machine(PROFILE)
    machine.connect()
    machine.home()
    program = ["G90 G0 X0 Y0 Z5", "M64 P0", "M64 P2", "M3 S1000", "M8",
               "G1 X40 F300", "G1 Y40 F300", "M65 P2", "M65 P0", "M5", "M9"]   # 16 s of dispensing
    errors: list[Exception] = []
    streamer = threading.Thread(target=lambda: _stream(machine, program, errors))
    streamer.start()
    try:
        assert wait_until(lambda: machine.progress is not None and machine.progress[0] >= 5, 30.0)
        assert lcnc_xyz.outputs()["dout"][:3] == [1, 0, 1]        # dispensing, mid-line
        with lcnc_xyz.watch(OUTPUTS, period_s=0.0005) as watch:
            stopped_ns = time.monotonic_ns()
            machine.stop()
            assert wait_until(lambda: watch.first("motion.digital-out-00", lambda v: v == 0, stopped_ns), 5.0)
        off_ms = (watch.first("motion.digital-out-00", lambda v: v == 0, stopped_ns) - stopped_ns) / 1e6
        print(f"dispense output off {off_ms:.1f} ms after the stop call (LinuxCNC's on-abort routine)")
        assert off_ms < 2000.0
    finally:
        streamer.join(30)
    assert errors, "the stopped program reported success"
    assert wait_until(lambda: _off(lcnc_xyz.outputs()) == ALL_OFF, 5.0), lcnc_xyz.outputs()
    assert lcnc_xyz.outputs()["task_state"] == 1                    # still in e-stop
    machine.connect()
    assert _off(lcnc_xyz.outputs()) == ALL_OFF
    with lcnc_xyz.watch(OUTPUTS, period_s=0.001) as watch:
        report = machine.stream(["G90 G0 Z25", "G0 X10 Y10 Z25"])   # travel only
    assert report.executed == report.total == 2
    assert watch.samples and all(values == [0, 0, 0, 0] for _, values in watch.samples), watch.samples
    assert _off(lcnc_xyz.outputs()) == ALL_OFF
    machine.disconnect()


def _stream(machine, program: list[str], errors: list[Exception]) -> None:
    try:
        machine.stream(program)
    except HardwareError as exc:
        errors.append(exc)


def _switch_on(sim, *commands: str) -> None:
    """Outputs switched on by someone else's session (a panel, a previous host process)."""
    session = sim.session(enable=True)
    try:
        session.set("mode", "mdi")
        for command in commands:
            session.set("mdi", command)
            session.set("wait", "done", timeout_s=10)
    finally:
        session.close()


@pytest.mark.parametrize("when", ["connect", "disconnect"])
def test_the_host_switches_the_profiles_outputs_off(lcnc_xyz, when):
    """Without any abort (so without the controller's ON_ABORT_COMMAND): ``connect`` and
    ``disconnect`` send the profile's ``dispense_off`` and ``outputs_off``."""
    profile = MachineProfile(**{**PROFILE.__dict__, "outputs_off": ("M65 P1", "M5")})
    machine = lcnc_xyz.machine(profile)
    machine.connect()
    machine.home()
    if when == "connect":
        machine.disconnect()
        _switch_on(lcnc_xyz, "M64 P0", "M64 P1", "M3 S500")
        assert lcnc_xyz.outputs()["dout"][:2] == [1, 1] and lcnc_xyz.outputs()["spindle"] == 1
        machine.connect()
    else:
        machine.send("M64 P0")
        machine.send("M64 P1")
        machine.send("M3 S500")
        assert lcnc_xyz.outputs()["dout"][:2] == [1, 1] and lcnc_xyz.outputs()["spindle"] == 1
        machine.disconnect()
    assert _off(lcnc_xyz.outputs()) == ALL_OFF
    if machine.state != "disconnected":
        machine.disconnect()


def test_through_the_api_stop_connect_and_a_travel_program_dispense_nothing(client, lcnc_env):
    """The operator's sequence: a print with ``M64 P0`` on, ``POST /stop`` mid-line,
    ``POST /connect``, then a travel-only print (two ``G0`` at Z25)."""
    from tests.conftest import auth
    from tests.hardware.linuxcnc.conftest import add_sim_machine
    from tests.jobs.test_jobs_api import wait_for

    op = auth("operator")
    machine_id = add_sim_machine(client, lcnc_env, {"dispense_on": "M64 P0", "dispense_off": "M65 P0",
                                                    "probe_command": "G38.2"}, op)
    machine = client.app.state.runtime.machines.get(machine_id)

    def upload(lines: list[str]) -> str:
        text = ("\n".join(lines) + "\n").encode()
        return client.post("/api/v1/programs", files={"file": ("p.ngc", text)}, headers=op).json()["id"]

    printing = upload(["G21", "G90", "G0 X0 Y0 Z5", "M64 P0", "G1 X40 F300", "G1 Y40 F300", "M65 P0"])
    job = client.post(f"/api/v1/machines/{machine_id}/print", json={"program_id": printing}, headers=op)
    assert job.status_code == 202, job.text
    assert wait_until(lambda: machine.progress is not None and machine.progress[0] >= 5, 60.0)
    assert lcnc_env.outputs()["dout"][0] == 1
    stop = client.post(f"/api/v1/machines/{machine_id}/stop", headers=op)
    assert stop.status_code == 200 and stop.json()["stop_sent"] is True, stop.text
    wait_for(client, job.json()["id"], timeout=60)
    assert wait_until(lambda: _off(lcnc_env.outputs()) == ALL_OFF, 5.0), lcnc_env.outputs()
    assert client.post(f"/api/v1/machines/{machine_id}/connect", headers=op).json()["state"] == "idle"
    assert _off(lcnc_env.outputs()) == ALL_OFF
    travel = upload(["G90", "G0 Z25", "G0 X10 Y10 Z25"])
    with lcnc_env.watch(OUTPUTS, period_s=0.001) as watch:
        job = client.post(f"/api/v1/machines/{machine_id}/print", json={"program_id": travel}, headers=op)
        done = wait_for(client, job.json()["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    assert watch.samples and all(values == [0, 0, 0, 0] for _, values in watch.samples), watch.samples
    client.post(f"/api/v1/machines/{machine_id}/disconnect", headers=op)
