"""The host against grbl 1.1h behaviour: each test names the defect it
pins down; every one failed against the host before its fix (see the commit messages)."""

from __future__ import annotations

import threading
import time

import pytest

from hardware.errors import FirmwareError, HardwareError, ProbeFailed
from hardware.link import Link
from hardware.machine import Machine, MachineProfile
from hardware.protocol import normalized_commands

GRBL = MachineProfile(dispense_on="M3 S1000", dispense_off="M5")


def _machine(url: str, **kwargs) -> Machine:
    kwargs.setdefault("timeout_s", 10)
    kwargs.setdefault("poke_s", 0.05)
    return Machine(url, "grbl", GRBL, boot_quiet_s=0.01, **kwargs)


def _link(url: str, **kwargs) -> Link:
    kwargs.setdefault("window", "pingpong")
    link = Link.open(url, dialect="grbl", **kwargs)
    time.sleep(0.05)
    link.unsolicited.clear()
    return link


def test_6_1_idle_while_dwelling_is_not_a_lost_ok(make_world):
    """$10=3 puts Bf: in the status; grbl reports Idle with an empty RX buffer while it
    dwells.  The dwell's own ok must answer it, and later replies stay with their lines."""
    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.0)
    link = _link(url, poke_s=0.05, timeout_s=5)
    try:
        assert link.send("$10=3").status == "ok"
        dwell = link.send("G4 P0.6")
        assert dwell.status == "ok" and dwell.t_done - dwell.t_sent >= 0.55
        with pytest.raises(FirmwareError) as info:
            link.send("G5 X1")
        assert info.value.code == 20 and info.value.command == "G5 X1"
        assert link.send("G1 X1 F600").status == "ok"
        assert link.stats["assumed_ok"] == 0 and link.stats["pokes"] > 0
    finally:
        link.close()


def test_6_2_a_long_dwell_is_not_a_dead_controller(make_world):
    """Pokes must keep coming while grbl is busy, so its status replies show it alive:
    a dwell several times longer than timeout_s completes."""
    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.0)
    link = _link(url, poke_s=0.05, timeout_s=0.5)
    try:
        result = link.send("G4 P1.6")
        assert result.status == "ok" and result.t_done - result.t_sent >= 1.55
    finally:
        link.close()


def test_6_3_connect_waits_for_the_boot_banner(make_world):
    """An Arduino resets when the port opens: the bootloader swallows input for ~0.5 s,
    then grbl prints (on a fresh EEPROM) error:7, its settings and the banner."""
    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.6, fresh_eeprom=True)
    machine = _machine(url, boot_wait_s=3.0)
    identity = machine.connect()
    try:
        assert identity.reset_detected
        assert any(line.startswith("Grbl 1.1h") for line in identity.banner)
        assert "error:7" in identity.banner
        assert identity.firmware == "grbl 1.1h.20190830"  # 6.11: no trailing colon
        assert world.stats.faults.get("lost_in_bootloader", 0) == 0  # nothing sent too early
        assert machine.state == "idle"
    finally:
        machine.disconnect()


def test_a_restart_between_two_commands_fails_the_session_before_the_next_line(make_world):
    """grbl restarts while the host waits between two lines (nothing in flight): its modal
    state (units, feed) is gone and its bootloader ignores input for a second.  The next line
    must not be sent: it would run without the program's feed ("Undefined feed rate") or
    never be answered."""
    from hardware.errors import FirmwareReset

    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.02)
    machine = _machine(url)
    machine.connect()
    machine.send("G21 G90 G1 F600")
    received = world.stats.lines_received
    world.reset_controller()
    deadline = time.monotonic() + 5.0
    while machine.link.session.fatal is None and time.monotonic() < deadline:
        time.sleep(0.01)  # the banner reaches the host's reader
    assert isinstance(machine.link.session.fatal, FirmwareReset)
    assert "restarted between two commands" in str(machine.link.session.fatal)
    with pytest.raises(HardwareError):  # the machine is in error: reconnect first
        machine.send("G1 X1")
    assert machine.state == "error"
    assert world.stats.lines_received == received  # nothing went into the new firmware session
    machine.disconnect()


def test_6_4_pingpong_stops_at_the_rejected_line(make_world):
    url, world = make_world(dialect="grbl")
    machine = _machine(url, window="pingpong")
    machine.connect()
    world.transcript.reset()
    before = world.stats.lines_received
    program = ["G1 X1 F600", "G1 X2", "G5 X1", "G1 X3", "G1 X4"]
    with pytest.raises(FirmwareError) as info:
        machine.stream(program)
    assert info.value.code == 20
    safe = normalized_commands(machine.profile.safe_off)  # every program starts with its outputs off
    assert world.transcript.commands == [*safe, "G1 X1 F600", "G1 X2"]
    assert world.stats.lines_received - before == len(safe) + 3  # nothing after the bad line reached grbl
    machine.disconnect()


def test_6_5_syntax_errors_are_not_resent(make_world):
    url, world = make_world(dialect="grbl")
    link = _link(url)
    try:
        before = world.stats.lines_received
        with pytest.raises(FirmwareError) as info:
            link.send("G1 XA")
        assert info.value.code == 2
        with pytest.raises(FirmwareError) as info:
            link.send("1G")
        assert info.value.code == 1
        assert world.stats.lines_received - before == 2 and link.stats["retries"] == 0
    finally:
        link.close()


def test_6_6_windowed_error_lets_queued_lines_finish_and_names_them(make_world):
    url, world = make_world(dialect="grbl")
    machine = _machine(url, window="windowed")
    machine.connect()
    world.transcript.reset()
    program = ["G21", "G90", "G1 X1 F600"] + [f"G1 X{i}" for i in range(2, 6)] + ["G5 X1"] + \
              [f"G1 Y{i}" for i in range(1, 21)]
    with pytest.raises(FirmwareError) as info:
        machine.stream(program)
    safe = normalized_commands(machine.profile.safe_off)  # every program starts with its outputs off
    assert world.transcript.commands[:len(safe)] == safe
    ran = world.transcript.commands[len(safe):]
    assert "G5 X1" not in ran and ran[:7] == normalized_commands(program)[:7]
    after = len(ran) - 7  # lines grbl already held when it rejected line 7
    assert after > 0
    assert info.value.line_index == 7
    assert machine.link.in_flight == 0 and machine.state == "idle"
    assert machine.resume_line() == 8 + after
    assert machine.link.mode == "windowed"
    machine.disconnect()


def test_6_7_leaving_check_mode_resets_without_poisoning_the_link(make_world):
    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.0)
    machine = _machine(url)
    machine.connect()
    assert "Enabled" in " ".join(machine.send("$C").reply_lines)
    machine.send("G1 X5 F600")  # checked, not run
    assert "Disabled" in " ".join(machine.send("$C").reply_lines)
    assert machine.send("G1 X1 F600").status == "ok"
    # the connect's safe_off, then the one command that ran (not the checked one)
    safe = normalized_commands(machine.profile.safe_off)
    assert machine.state == "idle" and world.transcript.commands == [*safe, "G1 X1 F600"]
    machine.disconnect()


def test_6_9_lost_oks_recover_without_the_buffer_field(make_world):
    """Stock grbl ($10=1) sends no Bf:; a lost ok is found by a $G sync marker."""
    from hardware.mock import FaultConfig

    url, world = make_world(dialect="grbl", faults=FaultConfig(drop_ok_rate=0.05, seed=3))
    link = _link(url, window="windowed", poke_s=0.02, timeout_s=5)
    try:
        world.transcript.reset()
        program = [f"G1 X{i % 50} Y{i // 50} F6000" for i in range(300)]
        pendings = [link.send_async(line) for line in program]
        link.wait_idle(20)
        assert world.transcript.commands == program
        assert all(p.result().status in ("ok", "assumed") for p in pendings)
        assert link.stats["assumed_ok"] >= world.stats.faults["drop_ok"]
    finally:
        link.close()


def test_6_9_homing_alarm_reset_does_not_poison_the_link(make_world):
    url, world = make_world(dialect="grbl", homing=True, homing_fails=True, time_scale=0.1,
                            boot_s=0.0)
    machine = _machine(url)
    machine.connect()
    with pytest.raises(FirmwareError) as info:
        machine.home()
    assert "ALARM:9" in " ".join(info.value.reply_lines)
    assert machine.controller_state() == "Alarm"
    machine.unlock()
    assert machine.send("G1 X1 F600").status == "ok"
    machine.disconnect()


def test_6_9_probe_already_triggered_is_not_no_surface(make_world):
    import trimesh

    block = trimesh.creation.box(extents=(20, 20, 10))  # top at z=5
    url, world = make_world(dialect="grbl", true_part=block)
    machine = _machine(url)
    machine.connect()
    machine.send("$X")
    with pytest.raises(ProbeFailed) as info:
        machine.probe(0.0, 0.0, z_start=2.0, z_min=-5.0)  # starts inside the block
    assert info.value.reason == "triggered_before_motion"
    with pytest.raises(ProbeFailed) as info:
        machine.probe(30.0, 30.0, z_start=2.0, z_min=1.0)  # nothing within reach
    assert info.value.reason == "no_contact"
    machine.disconnect()


def test_6_9_pause_is_a_feed_hold_on_the_controller(make_world):
    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.0)
    machine = _machine(url)
    machine.connect()
    program = ["G1 X0 F3000"] + [f"G1 X{i * 2} F3000" for i in range(1, 30)]  # 1.2 s of motion
    done = []
    thread = threading.Thread(target=lambda: done.append(machine.stream(program)))
    thread.start()
    time.sleep(0.3)
    machine.pause()
    time.sleep(0.05)
    held = world.firmware.machine_position(time.monotonic())
    time.sleep(0.3)
    assert world.firmware.machine_position(time.monotonic()) == held  # motion stopped
    assert machine.controller_state().startswith("Hold")
    machine.resume()
    thread.join(10)
    assert done and done[0].executed == len(program)
    assert world.position[0] == pytest.approx(58.0)
    machine.disconnect()


def test_6_11_jog_then_move_and_probe_waits_for_motion(make_world):
    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.0)
    machine = _machine(url)
    machine.connect()
    machine.jog(x=3.0, feed_mm_min=600)  # 0.3 s
    assert machine.move(x=1.0, feed_mm_min=3000) == pytest.approx((1.0, 0.0, 0.0), abs=1e-3)
    point = machine.probe(1.0, 0.0, z_start=1.0, z_min=-1.0, feed_mm_min=600)
    assert point.z == pytest.approx(0.0, abs=1e-3)
    assert not world.firmware.moving()  # retract finished before probe() returned
    machine.disconnect()


def test_6_11_rx_buffer_from_opt(make_world):
    url, world = make_world(dialect="grbl", rx_buffer=64)
    machine = _machine(url, window="windowed")
    machine.connect()
    assert machine.link.rx_buffer == 64
    world.transcript.reset()
    program = [f"G1 X{i % 50}.125 Y{i // 50}.250 F6000" for i in range(200)]
    machine.stream(program)
    safe = normalized_commands(machine.profile.safe_off)  # every program starts with its outputs off
    assert world.stats.rx_overflows == 0 and world.transcript.commands == [*safe, *program]
    machine.disconnect()


def test_6_11_status_shows_alarm_and_hold(make_world):
    url, world = make_world(dialect="grbl", homing=True)
    machine = _machine(url)
    machine.connect()
    assert machine.status()["controller"] == "Alarm"
    machine.home()
    assert machine.status()["controller"] == "Idle"
    machine.disconnect()


def test_6_8_resume_starts_at_what_moved_and_restores_the_modes(make_world):
    """grbl's ok means planned: at a USB drop ~15 acknowledged moves had not run and were
    lost with the reset.  resume_line() must not skip them, and the resumed stream must
    run in the program's modes (inches, relative, F, dispenser on) although grbl lost them."""
    from hardware.mock import FaultConfig

    url, world = make_world(dialect="grbl", time_scale=1.0, boot_s=0.0,
                            faults=FaultConfig(disconnect_at_line=45))
    machine = _machine(url, window="windowed")
    machine.connect()
    world.transcript.reset()
    # 1 mm steps at 1500 mm/min: 0.04 s each, so the planner is full while streaming
    program = ["G21", "G90", "G0 X0 Y0 Z1", "G20", "G91", "G1 X0.01 F60", "M3 S1000"] + \
              [f"G1 X{0.04 if i % 2 else -0.04:.2f} Y0.01" for i in range(60)] + ["M5"]
    with pytest.raises(HardwareError):  # the link drops at line 45
        machine.stream(program)
    safe = normalized_commands(machine.profile.safe_off)  # the program started with its outputs off
    assert world.transcript.commands[:len(safe)] == safe
    ran = len(world.transcript.commands) - len(safe)  # lines whose motion completed before the drop
    acked = machine.interrupted_program.acked_index
    assert acked - ran >= 10  # many acknowledged moves never ran
    machine.connect()
    start = machine.resume_line()
    assert start <= ran and ran - start <= machine.planner_blocks
    machine.stream(program, start_line=start)
    commands = normalized_commands(program)
    # the connect's safe_off (grbl reset: its outputs were off already), then safe_off and the replay
    assert world.transcript.commands == safe + commands[:ran] + safe + machine.last_preamble + commands[start:]
    assert machine.last_preamble[:2] == ["M5", "G20"] and machine.last_preamble[-3:] == \
        ["G1 F60", "G91", "M3 S1000"]
    # the tool ends where the uninterrupted program would have put it (inches, relative)
    end_x = 0.01 * 25.4 + 0.0
    end_y = sum(0.01 for _ in range(60)) * 25.4
    assert world.position[0] == pytest.approx(end_x, abs=1e-6)
    assert world.position[1] == pytest.approx(end_y, abs=1e-6)
    machine.disconnect()
