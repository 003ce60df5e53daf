"""Link: correlation, flow control, resends and fault soaks against the mock firmware."""

from __future__ import annotations

import threading
import time

import pytest

from hardware.errors import FirmwareError, InvalidConfig, LinkError
from hardware.events import PositionReport, ProbeReport
from hardware.link import Link
from hardware.mock import FaultConfig
from hardware.protocol import commands_sha256

ALL_CLASSES = {"checksum", "drop_ok", "duplicate_ok", "resend", "garbage", "busy", "slow"}


def _program(count: int) -> list[str]:
    return [f"G1 X{i % 200 * 0.1:.3f} Y{i // 200 % 200 * 0.1:.3f} F6000" for i in range(count)]


def _soak(make_world, dialect: str, window: str, count: int, faults: FaultConfig):
    url, world = make_world(dialect=dialect, faults=faults, keep_transcript=False)
    link = Link.open(url, dialect=dialect, window=window, timeout_s=10, poke_s=0.02)
    try:
        link.reset_line_numbers()
        world.transcript.reset()
        program = _program(count)
        for line in program:
            link.send_async(line)
        link.wait_idle(60)
        return world, link, program
    finally:
        link.close()


def test_soak_marlin_windowed_every_fault_class(make_world):
    world, link, program = _soak(make_world, "marlin", "windowed", 20_000,
                                 FaultConfig.uniform(0.01, seed=11))
    assert world.transcript.digest() == commands_sha256(program)
    assert set(world.stats.faults) == ALL_CLASSES
    assert min(world.stats.faults.values()) > 100
    assert link.stats["resends"] > 0 and link.mode == "windowed"


def test_soak_marlin_pingpong_every_fault_class(make_world):
    world, link, program = _soak(make_world, "marlin", "pingpong", 2_000,
                                 FaultConfig.uniform(0.01, seed=12))
    assert world.transcript.digest() == commands_sha256(program)
    assert set(world.stats.faults) == ALL_CLASSES


def test_soak_grbl_pingpong_faults(make_world):
    # grbl has no resend protocol ("resend", "busy") and no checksum: a line damaged on the
    # wire is the parser's error:1/2 (never re-sent, see test_grbl_host 6.5)
    faults = FaultConfig(drop_ok_rate=0.01, duplicate_ok_rate=0.01, garbage_rate=0.01,
                         slow_rate=0.01, seed=13)
    world, link, program = _soak(make_world, "grbl", "pingpong", 2_000, faults)
    assert world.transcript.digest() == commands_sha256(program)
    assert set(world.stats.faults) == {"drop_ok", "duplicate_ok", "garbage", "slow"}
    assert link.stats["retries"] == 0 and link.stats["assumed_ok"] > 0


def test_soak_grbl_windowed_recoverable_faults(make_world):
    faults = FaultConfig(drop_ok_rate=0.01, garbage_rate=0.01, slow_rate=0.01, seed=14)
    world, link, program = _soak(make_world, "grbl", "windowed", 5_000, faults)
    assert world.transcript.digest() == commands_sha256(program)
    assert link.mode == "windowed" and world.stats.rx_overflows == 0


def test_grbl_windowed_rejected_line_is_reported_on_its_own_line(make_world):
    url, world = make_world(dialect="grbl")
    link = Link.open(url, dialect="grbl", window="windowed", poke_s=0.02)
    try:
        pendings = [link.send_async(c) for c in ("G1 X1 F100", "G5 X1", "G1 X2")]
        with pytest.raises(FirmwareError) as info:
            pendings[1].result(5)
        assert info.value.code == 20
        assert pendings[2].result(5).status == "ok"
    finally:
        link.close()


def test_marlin_without_advanced_ok_falls_back_to_pingpong(make_world):
    world, link, program = _soak(make_world, "marlin", "windowed", 500,
                                 FaultConfig(checksum_rate=0.02, seed=5))
    assert link.mode == "windowed"
    url, world = make_world(dialect="marlin", advanced_ok=False,
                            faults=FaultConfig(checksum_rate=0.02, drop_ok_rate=0.02,
                                               duplicate_ok_rate=0.02, seed=8))
    link = Link.open(url, dialect="marlin", window="windowed", poke_s=0.02)
    try:
        link.reset_line_numbers()
        world.transcript.reset()
        program = _program(300)
        for line in program:
            link.send_async(line)
        link.wait_idle(30)
        assert link.mode == "pingpong" and "ADVANCED_OK" in link.fallbacks[0]
        assert world.transcript.digest() == commands_sha256(program)
    finally:
        link.close()


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_each_command_gets_its_own_replies(make_world, dialect):
    url, _ = make_world(dialect=dialect)
    link = Link.open(url, dialect=dialect, window="windowed", poke_s=0.02)
    try:
        moves = [link.send_async(c) for c in ("G1 X1 Y2 F600", "G1 X3 F600")]
        if dialect == "marlin":
            probe = link.send("G30 X3 Y2")
            position = link.send("M114")
            assert isinstance(position.payload, PositionReport)
            assert position.payload.axes["X"] == 3.0
        else:
            probe = link.send("G38.2 Z-5 F100")
        assert isinstance(probe.payload, ProbeReport) and probe.payload.z == 0.0
        assert [m.result().status for m in moves] == ["ok", "ok"]
        assert probe.t_done >= probe.t_sent and probe.reply_lines[-1].startswith("ok")
    finally:
        link.close()


def test_emergency_stop_does_not_wait_behind_the_queue(make_world):
    url, world = make_world(dialect="marlin", time_scale=1.0)
    link = Link.open(url, dialect="marlin", window="windowed", timeout_s=10)
    try:
        dwell = link.send_async("G4 P3000")
        queued = link.send_async("G1 X5 F600")
        time.sleep(0.1)
        start = time.monotonic()
        link.emergency_stop()
        with pytest.raises(FirmwareError):
            queued.result(1)
        with pytest.raises(FirmwareError):
            dwell.result(1)
        assert time.monotonic() - start < 0.5
        time.sleep(0.05)
        assert world.firmware.halted
        assert world.transcript.commands == []
    finally:
        link.close()


def test_silent_device_times_out_with_link_error():
    link = Link.open("loop://", dialect="marlin", timeout_s=0.3, poke_s=0.02)  # echoes, never answers
    try:
        with pytest.raises(LinkError):
            link.send("M115", 5)
    finally:
        link.close()


@pytest.mark.parametrize("url", ["/dev/ttyCONFORMA_NONE", "socket://127.0.0.1:9"])
def test_unreachable_port(url):
    with pytest.raises(LinkError) as info:
        Link.open(url)
    assert info.value.field == "port"


@pytest.mark.parametrize("kwargs,field", [
    ({"dialect": "repetier"}, "dialect"),
    ({"window": "huge"}, "window"),
])
def test_bad_link_arguments(kwargs, field):
    with pytest.raises(InvalidConfig) as info:
        Link.open("mock://linkargs", **kwargs)
    assert info.value.field == field


def test_malformed_mock_url_options():
    with pytest.raises(InvalidConfig) as info:
        Link.open("mock://x?checksum_rate=lots")
    assert info.value.field == "port.checksum_rate"


def test_send_from_many_threads_keeps_every_command(make_world):
    url, world = make_world(dialect="marlin", faults=FaultConfig(checksum_rate=0.02, seed=9))
    link = Link.open(url, dialect="marlin", window="windowed", poke_s=0.02)
    try:
        link.reset_line_numbers()
        world.transcript.reset()
        errors = []

        def worker(k: int) -> None:
            try:
                for i in range(200):
                    link.send(f"G1 X{k}.{i:03d}")
            except Exception as exc:  # pragma: no cover - reported below
                errors.append(exc)

        threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(30)
        assert not errors
        assert sorted(world.transcript.commands) == sorted(
            f"G1 X{k}.{i:03d}" for k in range(4) for i in range(200))
        for k in range(4):  # each thread's own commands stay in order
            mine = [c for c in world.transcript.commands if c.startswith(f"G1 X{k}.")]
            assert mine == sorted(mine)
    finally:
        link.close()


def test_busy_keepalives_keep_a_long_command_alive(make_world):
    url, world = make_world(dialect="marlin", time_scale=1.0)
    link = Link.open(url, dialect="marlin", window="pingpong", timeout_s=2.2)
    try:
        time.sleep(0.05)
        result = link.send("G4 P2500")  # silent for 2.0 s, then "echo:busy: processing"
        assert any("busy" in line for line in result.reply_lines)
        assert result.t_done - result.t_sent >= 2.4 and link.stats["pokes"] == 0
    finally:
        link.close()


def test_resend_beyond_the_bounded_history_is_a_protocol_error(make_world):
    from hardware.errors import ProtocolError

    url, _ = make_world(dialect="marlin")
    link = Link.open(url, dialect="marlin", window="windowed", history=16, poke_s=0.02)
    try:
        for i in range(40):
            link.send(f"G1 X{i}")
        with link._cond:  # the firmware asks for a line 40 lines back
            link._handle("Resend: 2")
        with pytest.raises(ProtocolError):
            link.send("G1 Y1", 2)
        assert not link.healthy
    finally:
        link.close()
