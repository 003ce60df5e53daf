"""Probe physics seen through the host (``Machine``) on both dialects: probe_toward,
G30 with a ball stylus, drift over G4 dwell, tool selection, deposits at the tool tip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hardware.dialects import dialect as dialect_rules
from hardware.errors import InvalidConfig, ProbeFailed
from hardware.machine import Machine, MachineProfile
from hardware.mock import MockPad, MockSphere, MockTool

GRBL_PROFILE = MachineProfile(dispense_on="M8", dispense_off="M9")
PAD = MockPad((50.0, 10.0, 5.0), 20.0)
SPHERE = MockSphere((100.0, 10.0, 12.0), 20.0)
OFFSET = (12.3, -4.1, -8.7)


def _connect(make_world, dialect: str, **kwargs) -> tuple[Machine, object]:
    url, world = make_world(dialect=dialect, **kwargs)
    profile = GRBL_PROFILE if dialect == "grbl" else MachineProfile()
    machine = Machine(url, dialect, profile, boot_wait_s=0.5, boot_quiet_s=0.01, poke_s=0.02,
                      timeout_s=10)
    machine.connect()
    return machine, world


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_probe_toward_pad_and_sphere(make_world, dialect):
    r, pre = 0.5, 0.015
    machine, world = _connect(make_world, dialect, stylus_radius_mm=r, pretravel_mm=pre,
                              pad=PAD, sphere=SPHERE)
    try:
        top = machine.probe_toward((52.0, 11.0, 10.0), (52.0, 11.0, 0.0))
        assert (top.x, top.y) == pytest.approx((52.0, 11.0), abs=1e-9)
        assert top.z == pytest.approx(5.0 + r - pre, abs=0.0005)  # 3-decimal reports
        assert machine.position() == pytest.approx((52.0, 11.0, 10.0), abs=0.01)  # back at start
        c = np.array(SPHERE.centre_mm)
        for angle in (0.0, 90.0, 200.0):
            u = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle)), 0.0])
            start = c + 14.0 * u
            hit = machine.probe_toward(tuple(start), tuple(c + 8.0 * u))
            assert np.linalg.norm(np.array([hit.x, hit.y, hit.z]) - c) == pytest.approx(
                10.0 + r - pre, abs=0.001)
        with pytest.raises(ProbeFailed):  # nothing between start and target
            machine.probe_toward((0.0, -40.0, 10.0), (0.0, -40.0, 2.0))
        assert machine.state == "idle"
        assert machine.position() == pytest.approx((0.0, -40.0, 10.0), abs=0.01)
        with pytest.raises(InvalidConfig) as info:
            machine.probe_toward((1.0, 2.0, 3.0), (1.0, 2.0, 3.0))
        assert info.value.field == "target"
    finally:
        machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_vertical_probe_with_a_ball_reads_centre_height(make_world, dialect):
    """The vertical ``probe`` (G30 on Marlin, G38.2 on grbl) meets the pad with the ball."""
    machine, world = _connect(make_world, dialect, stylus_radius_mm=0.75, pad=PAD)
    try:
        point = machine.probe(45.0, 8.0, z_start=10.0, z_min=-2.0)
        assert point.z == pytest.approx(5.75, abs=0.0005)
    finally:
        machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_drift_lowers_the_pad_reading_by_the_dwell(make_world, dialect):
    drift = 0.01  # mm/min, large so the 3-decimal reports resolve it
    machine, world = _connect(make_world, dialect, drift_mm_per_min=drift, pad=PAD)
    try:
        start, target = (50.0, 10.0, 8.0), (50.0, 10.0, 0.0)
        first = machine.probe_toward(start, target)
        clock_before = world.stats.machine_time_s
        machine.send("G4 S600" if dialect == "marlin" else "G4 P600")
        assert world.stats.machine_time_s - clock_before == pytest.approx(600.0)
        second = machine.probe_toward(start, target)
        # between the two G38.2 starts: the first touch down (at 100 mm/min), its retract
        # (3000 mm/min) and the dwell; the host's travel moves are zero-length
        down = start[2] - first.z
        elapsed = 600.0 + down / 100.0 * 60.0 + down / 3000.0 * 60.0
        assert first.z - second.z == pytest.approx(drift * elapsed / 60.0, abs=0.0011)
        assert first.z - second.z > 0.09
    finally:
        machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_tool_selection_and_deposits_at_the_tip(make_world, dialect):
    machine, world = _connect(make_world, dialect, tools=(MockTool(OFFSET, 0.8),), pad=PAD,
                              sphere=SPHERE)
    on, off = dialect_rules(dialect).dispense  # the dialect's default output, the mock's dispenser
    try:
        machine.select_tool(1)
        assert world.active_tool == 1
        machine.stream(["G1 X0 Y0 Z20 F3000", on, "G1 X10 Y5 Z20 F600", off])
        move = world.deposition_log[-1]
        assert move.start == pytest.approx(np.add((0, 0, 20), OFFSET))
        assert move.end == pytest.approx(np.add((10, 5, 20), OFFSET))
        # the nozzle's flat end on the pad: carriage z = pad top - offset z
        start = np.array([52.0, 10.0, 5.0 + 3.0]) - OFFSET
        hit = machine.probe_toward(tuple(start), tuple(start - (0, 0, 6)))
        assert hit.z == pytest.approx(5.0 - OFFSET[2], abs=0.0005)
        # side touches on the sphere from -x and +x: midpoint = c_x - offset_x
        c = np.array(SPHERE.centre_mm)
        xs = []
        for side in (-1.0, 1.0):
            tip = c + (side * 13.0, 0.0, -2.0)
            start = tip - OFFSET
            hit = machine.probe_toward(tuple(start), tuple(start - (side * 4.0, 0.0, 0.0)))
            xs.append(hit.x)
        assert sum(xs) / 2 == pytest.approx(c[0] - OFFSET[0], abs=0.001)
        assert xs[1] - xs[0] == pytest.approx(2 * (10.0 + 0.4), abs=0.002)
        machine.select_tool(0)
        assert world.active_tool == 0
        machine.stream([on, "G1 X20 Y5 Z20 F600", off])
        assert world.deposition_log[-1].end == pytest.approx((20, 5, 20))
        if dialect == "marlin":
            with pytest.raises(InvalidConfig) as info:
                machine.select_tool(3)  # echo:T3 Invalid extruder
            assert info.value.field == "tool" and world.active_tool == 0
        with pytest.raises(InvalidConfig):
            machine.select_tool(-1)
    finally:
        machine.disconnect()


def test_grbl_keeps_the_t_word_and_refuses_m6(make_world):
    import serial

    from hardware.protocol import parse_reply

    url, world = make_world(dialect="grbl", tools=(MockTool(OFFSET, 0.8),), boot_s=0.0)
    port = serial.serial_for_url(url, timeout=0.05)
    port.read(4096)

    def exchange(line: str) -> list[str]:
        port.write(line.encode() + b"\n")
        data = port.read(port.in_waiting or 1)
        while port.in_waiting:
            data += port.read(port.in_waiting)
        return [str(getattr(parse_reply(x, "grbl"), "raw", x)) for x in data.decode().splitlines()]

    try:
        assert exchange("T1") == ["ok"] and world.active_tool == 1
        assert exchange("M6") == ["error:20"]
        assert exchange("T300") == ["error:38"]
        assert exchange("G38.2 F100") == ["error:26"]
    finally:
        port.close()


def test_marlin_unknown_tool_and_m114_detail(make_world):
    machine, world = _connect(make_world, "marlin")
    try:
        reply = machine.send("T2")
        assert any("T2 Invalid extruder" in line for line in reply.reply_lines)
        machine.move(1.2345, 2.5, 3.0)
        detail = machine.send("M114 D")
        assert any(line.startswith("Logical: X:1.234 Y:2.500 Z:3.000") or
                   line.startswith("Logical: X:1.235 Y:2.500 Z:3.000") for line in detail.reply_lines)
    finally:
        machine.disconnect()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_machine_clock_counts_moves_and_dwell(make_world, dialect):
    machine, world = _connect(make_world, dialect)
    try:
        machine.stream(["G1 X30 Y40 F600", "G4 P2000" if dialect == "marlin" else "G4 P2"])
        assert world.stats.machine_time_s == pytest.approx(50.0 / 600.0 * 60.0 + 2.0)
    finally:
        machine.disconnect()


def test_a_nozzle_moved_into_the_part_counts_a_collision(make_world):
    import trimesh

    part = trimesh.creation.box((20.0, 20.0, 6.0))  # top face at z = 3
    machine, world = _connect(make_world, "marlin", true_part=part, tools=(MockTool(OFFSET, 0.8),))
    try:
        o = np.array(OFFSET)
        machine.stream([f"G1 X{-o[0]:.4f} Y{-o[1]:.4f} Z{10 - o[2]:.4f} F3000"])   # with T0, up and over
        machine.select_tool(1)
        machine.stream([f"G1 Z{3.2 - o[2]:.4f}"])                                   # tip 0.2 mm above: fine
        assert world.stats.collisions == 0
        machine.stream([f"G1 Z{2.9 - o[2]:.4f}"])                                   # tip into the top face
        assert world.stats.collisions == 1
        with pytest.raises(ProbeFailed):  # a nozzle probing the (non-conductive) part never triggers
            machine.probe_toward(tuple((0, 0, 5) - o), tuple((0, 0, 1) - o))
        assert world.stats.collisions == 2
    finally:
        machine.disconnect()


def test_the_url_seed_seeds_the_physics_noise_too():
    """``mock://NAME?seed=S`` seeds the pre-travel scatter and probe noise as well as the fault
    plan: two worlds with one seed read alike, another seed reads differently."""
    from hardware.mock import unregister_world

    def pad_readings(name: str, seed: int) -> list[float]:
        url = (f"mock://{name}?seed={seed}&pretravel_mm=0.015&pretravel_sd_mm=0.002&probe_noise_mm=0.001"
               "&pad=50,10,5,20")
        machine = Machine(url, "marlin", MachineProfile(), boot_wait_s=0.5, boot_quiet_s=0.01, poke_s=0.02,
                          timeout_s=10)
        machine.connect()
        try:
            return [machine.probe_toward((52.0, 11.0, 10.0), (52.0, 11.0, 0.0)).z for _ in range(4)]
        finally:
            machine.disconnect()
            unregister_world(name)

    first, again, other = pad_readings("seed-a", 3), pad_readings("seed-b", 3), pad_readings("seed-c", 4)
    assert first == again
    assert first != other
