"""Firmware dialects as data (``hardware.dialects``) and the lazy ``mock://`` scheme."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from hardware.dialects import DEFAULT_DIALECT, DIALECTS, GRBL, MARLIN, UnknownDialect, dialect
from hardware.errors import InvalidConfig
from hardware.protocol import parse_reply

ROOT = Path(__file__).resolve().parents[2]


def test_lookup_and_precise_error_for_an_unknown_name():
    assert dialect("marlin") is MARLIN and dialect("grbl") is GRBL
    assert DEFAULT_DIALECT in DIALECTS
    with pytest.raises(UnknownDialect) as info:
        dialect("smoothie")
    assert isinstance(info.value, InvalidConfig) and info.value.field == "dialect"
    assert "marlin" in info.value.message and "grbl" in info.value.message
    with pytest.raises(InvalidConfig):
        parse_reply("ok", "smoothie")


def test_records_are_frozen_and_say_what_differs():
    with pytest.raises(dataclasses.FrozenInstanceError):
        MARLIN.home_command = "$H"  # type: ignore[misc]
    assert (MARLIN.estop_bytes, GRBL.estop_bytes) == (b"M112\n", b"\x18")
    assert (MARLIN.wait_moves, GRBL.wait_moves) == ("M400", "G4 P0")
    assert (MARLIN.identify_command, GRBL.identify_command) == ("M115", "$I")
    assert MARLIN.line_numbers and not GRBL.line_numbers
    assert (MARLIN.window, GRBL.window) == ("slots", "bytes")
    assert GRBL.line_bytes("G1 X1") == 6 and MARLIN.line_bytes("G1 X1") == 21
    assert MARLIN.position_request == b"S000\n" and MARLIN.request_queued
    assert GRBL.position_request == b"?" and not GRBL.request_queued


def test_start_is_a_banner_only_where_the_dialect_says_so():
    assert type(parse_reply("start", "marlin")).__name__ == "StartBanner"
    assert type(parse_reply("start", "grbl")).__name__ == "Unknown"


def test_no_dialect_name_branches_outside_the_tables():
    """Callers read fields; only the mock picks its firmware class by name (a table)."""
    pattern = r'dialect ==\|dialect !=\|dialect in\|== "marlin"\|== "grbl"'
    found = subprocess.run(["grep", "-rn", pattern, "app", "hardware", "--include=*.py"], cwd=ROOT,
                           capture_output=True, text=True).stdout.splitlines()
    assert found == []


def test_mock_scheme_is_registered_on_first_use_not_on_import():
    code = (
        "import sys, serial\n"
        "import hardware.link, hardware.machine\n"
        "assert 'hardware.mock' not in sys.modules, 'imported by the link'\n"
        "assert 'hardware.mock' not in serial.protocol_handler_packages\n"
        "link = hardware.link.Link.open('mock://lazy?time_scale=0', dialect='grbl', timeout_s=5)\n"
        "assert 'hardware.mock' in sys.modules\n"
        "port = serial.serial_for_url('mock://lazy2?time_scale=0', timeout=0.05)\n"
        "port.close(); link.close()\n"
        "print('ok')\n")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "ok"
