"""Printrun's printcore (a real, independent host) against the mock's Marlin personality
on a pseudo-terminal and on TCP: what the firmware executed equals the program, exactly
once and in order, although 1 % of the lines arrive damaged and must be resent."""

from __future__ import annotations

from hardware.events import PositionReport, TemperatureReport
from hardware.mock import get_world
from hardware.mock.expose import PtyBridge, TcpMockServer
from hardware.protocol import commands_sha256, normalized_commands, parse_reply

from .printrun_host import program, stream_with_printcore


def test_printcore_streams_2000_lines_through_resends_exactly_once(make_world):
    url, world = make_world(dialect="marlin")
    world.faults.checksum_rate = 0.005
    world.faults.line_number_rate = 0.005
    world.faults.seed = 18
    lines = program(2000)
    with PtyBridge(url) as bridge:
        run = stream_with_printcore(bridge.path, lines, query_every_s=0.2)
    assert world.transcript.commands == normalized_commands(lines)
    assert world.transcript.digest() == commands_sha256(lines)
    faults = world.stats.faults
    assert faults.get("checksum", 0) >= 3 and faults.get("line_number", 0) >= 3, faults
    temperature = parse_reply(run.temperatures[-1].removeprefix("ok").strip())  # "ok T:.."
    assert isinstance(temperature, TemperatureReport) and temperature.current["T"] == 21.5
    position = parse_reply(run.positions[-1])
    assert isinstance(position, PositionReport)
    assert (position.axes["X"], position.axes["Y"]) == tuple(round(v, 2) for v in world.position[:2])


def test_printcore_over_tcp(make_world):
    url, world = make_world(dialect="marlin")
    lines = program(200)
    with TcpMockServer(url) as server:
        host, port = server.address
        run = stream_with_printcore(f"{host}:{port}", lines)
    assert world.transcript.commands == normalized_commands(lines)
    assert isinstance(parse_reply(run.temperatures[-1][2:].strip()), TemperatureReport)
    assert get_world(url.removeprefix("mock://")) is world
