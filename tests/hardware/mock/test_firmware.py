"""Mock firmware seen through a raw pyserial port: it must behave like Marlin / grbl."""

from __future__ import annotations

import time

import pytest
import serial

import hardware.mock  # noqa: F401  (registers mock://)
from hardware import events
from hardware.mock import FaultConfig
from hardware.protocol import commands_sha256, frame, parse_reply


def _open(url: str) -> serial.SerialBase:
    return serial.serial_for_url(url, timeout=0.05)


def _exchange(port, line: str, dialect: str = "marlin") -> list:
    port.write(line.encode() + b"\n")
    data = port.read(port.in_waiting or 1)
    while port.in_waiting:
        data += port.read(port.in_waiting)
    return [parse_reply(x, dialect) for x in data.decode("utf-8", "replace").splitlines()]


def test_marlin_boot_banner_and_line_protocol(make_world):
    url, world = make_world(dialect="marlin")
    port = _open(url)
    boot = [parse_reply(x) for x in port.read(4096).decode().splitlines()]
    assert isinstance(boot[0], events.StartBanner)
    assert isinstance(_exchange(port, frame(0, "M110 N0"))[-1], events.Ok)
    reply = _exchange(port, frame(1, "G1 X1 Y2 F600"))
    assert reply == [events.Ok("N1 P16 B3", 1, 16, 3, raw="ok N1 P16 B3")]
    # wrong line number: error with Last Line, then Resend and a plain ok
    reply = _exchange(port, frame(5, "G1 X2"))
    assert [type(e) for e in reply] == [events.FirmwareErrorEvent, events.Resend, events.Ok]
    assert reply[0].kind == "line_number" and reply[0].last_line == 1 and reply[1].line == 2
    # bad checksum
    reply = _exchange(port, "N2 G1 X2*1")
    assert reply[0].kind == "checksum" and reply[1].line == 2
    # no checksum with a line number
    reply = _exchange(port, "N2 G1 X2")
    assert reply[0].kind == "no_checksum"
    # M114 reports the planned position
    reply = _exchange(port, frame(2, "M114"))
    assert reply[0].axes == {"X": 1.0, "Y": 2.0, "Z": 0.0, "E": 0.0}
    assert world.transcript.commands == ["G1 X1 Y2 F600"]  # queries and rejected lines left out
    port.close()


def test_marlin_unknown_command_and_identify(make_world):
    url, _ = make_world(dialect="marlin")
    port = _open(url)
    port.read(4096)
    reply = _exchange(port, "G999")
    assert isinstance(reply[0], events.Echo) and "Unknown command" in reply[0].text
    reply = _exchange(port, "M115")
    assert isinstance(reply[0], events.FirmwareInfo)
    caps = {e.name: e.enabled for e in reply if isinstance(e, events.Capability)}
    assert caps["ADVANCED_OK"] is True


def test_grbl_probe_alarm_and_unlock(make_world):
    url, world = make_world(dialect="grbl")
    port = _open(url)
    assert isinstance(parse_reply(port.read(4096).decode().strip(), "grbl"), events.StartBanner)
    assert _exchange(port, "G0 Z5", "grbl") == [events.Ok(raw="ok")]
    reply = _exchange(port, "G38.2 Z-1 F100", "grbl")
    assert reply[0] == events.ProbeReport(0.0, 0.0, 0.0, True, raw="[PRB:0.000,0.000,0.000:1]")
    _exchange(port, "G0 Z5", "grbl")
    reply = _exchange(port, "G38.2 Z1 F100", "grbl")  # the bed at z=0 is out of reach
    assert reply == [events.Alarm(5, reply[0].message, raw="ALARM:5"),
                     events.ProbeReport(0.0, 0.0, 1.0, False, raw="[PRB:0.000,0.000,1.000:0]"),
                     events.Ok(raw="ok")]
    assert _exchange(port, "G1 X1 F100", "grbl")[0].code == 9  # locked
    reply = _exchange(port, "$X", "grbl")
    assert isinstance(reply[0], events.Message) and isinstance(reply[-1], events.Ok)
    assert isinstance(_exchange(port, "G1 X1 F100", "grbl")[0], events.Ok)
    port.write(b"?")
    status = parse_reply(port.read(4096).decode().strip(), "grbl")
    assert status.state == "Idle" and status.mpos == (1.0, 0.0, 1.0)
    assert _exchange(port, "G5 X1", "grbl")[0].code == 20


def test_deposition_log_records_dispensing_moves(make_world):
    url, world = make_world(dialect="grbl", dispense_on="M3 S1000", dispense_off="M5")
    port = _open(url)
    port.read(4096)
    for line in ("G1 X1 F600", "M3 S1000", "G1 X2 Y1 F300", "G1 X3", "M5", "G1 X4"):
        _exchange(port, line, "grbl")
    log = world.deposition_log
    assert [(m.start, m.end, m.feed_mm_min) for m in log] == [
        ((1.0, 0.0, 0.0), (2.0, 1.0, 0.0), 300.0), ((2.0, 1.0, 0.0), (3.0, 1.0, 0.0), 300.0)]


def test_transcript_digest_matches_program_definition(make_world):
    url, world = make_world(dialect="grbl")
    port = _open(url)
    port.read(4096)
    program = ["G21 ; mm", "G90", "(comment)", "G1 X1 F100", "$I"]
    for line in program:
        _exchange(port, line, "grbl")
    assert world.transcript.digest() == commands_sha256(["G21", "G90", "G1 X1 F100"])


def test_disconnect_keeps_sent_bytes_readable_then_raises(make_world):
    url, world = make_world(dialect="marlin", faults=FaultConfig(disconnect_at_line=2))
    port = _open(url)
    port.read(4096)
    port.write((frame(1, "G1 X1") + "\n" + frame(2, "G1 X2") + "\n").encode())
    assert port.read(200).decode().startswith("ok N1")  # sent before the drop
    with pytest.raises(serial.SerialException):
        port.read(10)
    with pytest.raises(serial.SerialException):
        port.write(b"M114\n")
    assert world.transcript.commands == ["G1 X1", "G1 X2"]
    again = _open(url)  # Marlin keeps running and keeps its line number
    reply = _exchange(again, frame(2, "G1 X2"))
    assert reply[0].kind == "line_number" and reply[0].last_line == 2


def test_baud_rate_timing_at_real_time_scale(make_world):
    url, _ = make_world(dialect="grbl", time_scale=1.0, latency_ms=0.0)
    port = serial.serial_for_url(url, baudrate=9600, timeout=1.0)
    port.read(port.in_waiting or 1)
    time.sleep(0.05)
    port.read(port.in_waiting or 0)
    line = b"G4 P0" + b" " * 90 + b"\n"  # 96 bytes at 9600 baud = 0.1 s on the wire
    start = time.monotonic()
    port.write(line)
    assert port.read(3) == b"ok\n"
    elapsed = time.monotonic() - start
    # 96 bytes in + 3 bytes out at 10 bits per byte
    assert 99 * 10 / 9600 * 0.95 < elapsed < 0.5, elapsed


def test_grbl_status_report_follows_the_10_mask_and_states(make_world):
    url, world = make_world(dialect="grbl", line_numbers=True)
    port = _open(url)
    port.read(4096)

    def status():
        port.write(b"?")
        return parse_reply(port.read(4096).decode().strip(), "grbl")

    first = status()  # stock $10=1: machine position, no buffer field; WCO after a reset
    assert first.state == "Idle" and first.mpos == (0.0, 0.0, 0.0)
    assert "Bf" not in first.fields and "WCO" in first.fields
    assert "WCO" not in status().fields
    assert isinstance(_exchange(port, "$10=2", "grbl")[-1], events.Ok)
    second = status()
    assert second.wpos == (0.0, 0.0, 0.0) and second.fields["Bf"] == "15,127"
    reply = _exchange(port, "$I", "grbl")
    assert reply[0] == events.FirmwareInfo({"VER": "1.1h.20190830:"}, raw="[VER:1.1h.20190830:]")
    assert reply[1].raw == "[OPT:VN,15,128]"
    # G-code during a jog is locked; a line number shows in Ln: while its block runs
    assert _exchange(port, "G1 XA", "grbl")[0].code == 2
    assert _exchange(port, "1G", "grbl")[0].code == 1
    assert _exchange(port, "G1 X1", "grbl")[0].code == 22  # grbl boots with no feed rate
    port.write(b"!")
    assert status().state == "Hold:0"
    port.write(b"~")
    assert status().state == "Idle"


def test_grbl_boot_messages_and_check_mode(make_world):
    url, world = make_world(dialect="grbl", fresh_eeprom=True, homing=True)
    port = _open(url)
    boot = port.read(8192).decode().splitlines()
    assert boot[0] == "error:7" and "$22=1" in boot  # EEPROM restored, settings printed
    assert boot[-2:] == ["Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]
    assert _exchange(port, "G0 X1", "grbl")[0].code == 9  # locked until homed
    assert isinstance(_exchange(port, "$H", "grbl")[-1], events.Ok)
    assert [e.raw for e in _exchange(port, "$C", "grbl")] == ["[MSG:Enabled]", "ok"]
    _exchange(port, "G1 X5 F100", "grbl")
    reply = [e.raw for e in _exchange(port, "$C", "grbl")]
    assert reply[:2] == ["[MSG:Disabled]", "ok"] and "Grbl 1.1h ['$' for help]" in reply
    assert world.transcript.commands == []  # nothing ran in check mode
    again = serial.serial_for_url(url, timeout=0.05)  # re-opening: EEPROM kept, no error:7
    assert "error:7" not in again.read(4096).decode()


def test_marlin_replies_as_documented(make_world):
    url, world = make_world(dialect="marlin", time_scale=1.0, latency_ms=0.0)
    port = serial.serial_for_url(url, baudrate=115200, timeout=3.0)
    time.sleep(0.1)
    port.read(port.in_waiting)  # the boot banner
    port.write(b"M105\n")  # temperatures on the ok line, no ADVANCED_OK fields
    line = port.readline().decode().strip()
    assert line.startswith("ok T:") and isinstance(parse_reply(line[2:].strip()), events.TemperatureReport)
    port.write((frame(1, "M110 N0") + "\n").encode())
    port.readline()
    port.write((frame(1, "G1 X30 F1800") + "\n").encode())  # 1 s of motion
    assert port.readline().decode().strip() == "ok N1 P15 B3"  # planned, not moved
    start = time.monotonic()
    port.write((frame(2, "M400") + "\n").encode())
    assert port.readline().decode().strip().startswith("ok N2")
    assert time.monotonic() - start > 0.8  # M400 waited for the move to finish
    port.write((frame(3, "M114") + "\n").encode())
    assert parse_reply(port.readline().decode()).axes["X"] == 30.0
