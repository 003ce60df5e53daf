"""A stop stops the process too: after an emergency stop mid-print and a reconnect every
process output is off by LinuxCNC's own status (``linuxcnc.stat``), and a travel-only
program dispenses nothing (the dispense output ``motion.digital-out-00`` sampled from HAL
the whole time).  The host's own part (``safe_off`` by MDI on connect and disconnect) is
tested apart from the controller's ``ON_ABORT_COMMAND``."""

from __future__ import annotations

import threading

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
        machine.stop()
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
