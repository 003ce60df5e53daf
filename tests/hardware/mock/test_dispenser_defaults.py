"""Every home of the default dispenser commands agrees with the G-code writer's one table
(``hardware`` may not import ``app``: its own table is held equal here), and the mock firmware
dispenses exactly the moves a program written with the defaults dispenses."""

from __future__ import annotations

import numpy as np
import pytest
import serial
import trimesh

import hardware.mock  # noqa: F401  (registers mock://)
from app.api.machine_schemas import MachineCreate, Profile
from app.compensation.standoff import CompensationError, CompensationParams
from app.gcode.fdm import FdmParams, write_fdm_gcode
from app.gcode.reader import DEFAULT_OFF, DEFAULT_ON, ReadOptions, read_program
from app.gcode.writer import DIALECT_NAMES, DIALECTS, DISPENSING_DIALECTS, own_dispense
from app.jobs.kinds.compensate import CompensateParams
from app.jobs.kinds.toolpath import ToolpathJobParams
from app.machines.dispenser import machine_dispense
from app.slicing import SliceParams, slice_mesh
from app.slicing.toolpath import ToolpathParams, plan_toolpath
from hardware import dialects as host
from hardware.machine import Machine
from hardware.machine_types import MachineProfile
from hardware.protocol import frame

SERIAL = tuple(host.DIALECTS)


def test_the_writer_declares_the_serial_dialects_pairs_and_none_for_linuxcnc():
    assert DISPENSING_DIALECTS == SERIAL == ("marlin", "grbl")
    assert own_dispense("marlin") == ("M106 S255", "M107")  # the fan at full duty, spelled out
    assert own_dispense("grbl") == ("M8", "M9")             # flood coolant: a plain pin, no S word
    assert DIALECTS["linuxcnc"].dispense is None


@pytest.mark.parametrize("name", DIALECT_NAMES)
def test_every_home_agrees_with_the_writers_table(name):
    on, off = machine_dispense(name)
    if name == "linuxcnc":
        assert (on, off) == host.LINUXCNC_DISPENSE
        with pytest.raises(CompensationError) as raised:
            CompensationParams(dialect=name)  # no dispenser of its own: the request must name one
        assert raised.value.field == "dispense_on"
    else:
        assert (on, off) == own_dispense(name) == host.DIALECTS[name].dispense
        compensation = CompensationParams(dialect=name)
        assert (compensation.dispense_on, compensation.dispense_off) == compensation.dispense == (on, off)
        assert Machine(f"mock://unused-{name}", name).profile.dispense_on == on
        assert Machine(f"mock://unused-{name}", name).profile.safe_off[0] == off
        assert on.split(" ")[0] in DEFAULT_ON and off.split(" ")[0] in DEFAULT_OFF
    created = MachineCreate(name="m", port="mock://", dialect=name)
    assert (created.profile.dispense_on, created.profile.dispense_off) == (on, off)
    own = MachineCreate(name="m", port="mock://", dialect=name, profile=Profile(dispense_on="M42 P4 S255",
                                                                               dispense_off="M42 P4 S0"))
    assert own.profile.dispense_on == "M42 P4 S255"  # a profile's own commands win


def test_the_kinds_leave_the_default_to_the_dialect_and_name_each_dialects_command():
    assert CompensateParams.model_fields["dispense_on"].default is None
    assert ToolpathJobParams.model_fields["dispense_on"].default is None
    described = CompensateParams.model_fields["dispense_on"].description or ""
    assert all(f"{name} {own_dispense(name)[0]}" in described for name in DISPENSING_DIALECTS)
    machine_text = Profile.model_fields["dispense_off"].description or ""
    assert all(f"{name} {machine_dispense(name)[1]}" in machine_text for name in DIALECT_NAMES)


def test_a_profile_made_without_commands_is_marlins():
    assert (MachineProfile().dispense_on, MachineProfile().dispense_off) == own_dispense("marlin")


@pytest.fixture(scope="module")
def toolpath():
    res = slice_mesh(trimesh.creation.box((6, 4, 0.2)), SliceParams(layer_mm=0.2))
    return plan_toolpath(res, ToolpathParams(pattern="raster", perimeters=1))


def _send(port: serial.SerialBase, line: str) -> str:
    port.write(line.encode() + b"\n")
    data = port.read(port.in_waiting or 1)
    while port.in_waiting:
        data += port.read(port.in_waiting)
    return data.decode("utf-8", "replace")


@pytest.mark.parametrize("name", SERIAL)
def test_the_mock_firmware_dispenses_the_moves_the_written_program_dispenses(name, toolpath, make_world):
    """The writer's default program, sent line by line to the mock firmware of its dialect
    (whose dispenser is wired to the dialect's default output): the moves the mock deposits are
    the program's dispensing moves as the reader finds them from the default command words."""
    text = write_fdm_gcode(toolpath, FdmParams(dialect=name, mode="dispense", home=False))
    on, off = own_dispense(name)
    assert text.count(f"\n{on}\n") >= 1 and text.count(f"\n{off}\n") >= 1
    url, world = make_world(dialect=name)
    port = serial.serial_for_url(url, timeout=0.05)
    port.read(4096)
    framed = name == "marlin"
    if framed:
        _send(port, frame(0, "M110 N0"))
    n = 0
    for raw in text.splitlines():
        line = raw.split(";")[0].strip()
        if not line:
            continue
        n += 1
        reply = _send(port, frame(n, line) if framed else line)
        assert "rror" not in reply, (line, reply)
    program = read_program(text, ReadOptions())
    moved = np.linalg.norm(program.end[:, :3] - program.start[:, :3], axis=1) > 0
    expected = program.end[program.dispense & moved, :3]
    deposited = np.array([m.end for m in world.deposition_log])
    assert len(deposited) == len(expected) > 0
    np.testing.assert_allclose(deposited, expected, atol=1e-3)
    n += 1
    _send(port, frame(n, "G1 X0 Y0 F600") if framed else "G1 X0 Y0 F600")
    assert len(world.deposition_log) == len(expected)  # the program's last off command held


def test_the_mock_grbl_models_spindle_and_coolant_as_grbl_does(make_world):
    """grbl's spindle is PWM at the modal S (0 after a reset: a bare ``M3`` switches nothing),
    its coolant a plain pin; ``$G`` reports both, a soft reset clears both."""
    url, world = make_world(dialect="grbl", dispense_on="M3 S1000", dispense_off="M5")
    port = serial.serial_for_url(url, timeout=0.05)
    port.read(4096)
    _send(port, "G1 X1 F600")
    _send(port, "M3")                                    # S0: no output, nothing deposited
    _send(port, "G1 X2")
    assert world.deposition_log == [] and world.outputs["spindle"] == 0.0
    assert " M3 M9 " in _send(port, "$G")
    _send(port, "M3 S1000")
    _send(port, "G1 X3")
    assert len(world.deposition_log) == 1 and world.outputs["spindle"] == 1000.0
    _send(port, "M5")
    _send(port, "M8")
    _send(port, "G1 X4")
    assert len(world.deposition_log) == 1 and world.outputs["M8"] == 1.0
    modes = _send(port, "$G")
    assert " M5 M8 " in modes and " S1000]" in modes     # the modal S stays
    port.write(b"\x18")                                  # soft reset: spindle and coolant off
    port.read(4096)
    assert world.outputs["M8"] == 0.0 and world.outputs["spindle"] == 0.0
