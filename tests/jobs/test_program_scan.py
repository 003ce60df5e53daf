"""Programs are scanned as a stream: the same facts as the whole-text reader, in any pieces,
with memory that does not grow with the number of lines; non-finite numbers refused."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from app.domain.errors import InvalidInput
from app.gcode.reader import read_program
from app.jobs.gcode_meta import ProgramScan, gcode_meta
from hardware.protocol import commands_sha256

PROGRAM = """; header
G21 G90
G28
G0 X10 Y5 Z2
G1 Z0.5 F600
G2 X20 Y5 I5 J0
G91
G1 X-3 Y4 (relative)\r
G90
G92 X0 Y0
G1 X1 Y1
G20
G1 X1 Y-1 Z0.1
G3 X0 Y0 I-0.5 J0.5
M2
"""


def _scan(data: bytes, piece: int) -> dict:
    scan = ProgramScan()
    for k in range(0, len(data), piece):
        scan.feed(data[k:k + piece])
    return scan.result()


@pytest.mark.parametrize("piece", [1, 3, 7, 64, 10_000])
def test_any_pieces_give_the_whole_texts_facts(piece):
    data = PROGRAM.encode()
    meta = _scan(data, piece)
    chords = read_program(PROGRAM).bounds()      # the arcs' chord ends: on the arcs, within 0.002 mm of their extremes
    low, high = np.array(meta["bounds"])
    assert (low <= chords[0]).all() and (high >= chords[1]).all()
    np.testing.assert_allclose(meta["bounds"], chords, atol=0.002 + 1e-9, rtol=0)
    digest = commands_sha256(PROGRAM.splitlines())
    assert (meta["lines"], meta["commands"], meta["commands_sha256"]) == (
        len(PROGRAM.splitlines()), digest.count, digest.sha256)
    assert meta == {**gcode_meta(PROGRAM), "sha256": meta["sha256"], "bytes": len(data)}


def test_a_crlf_split_between_pieces_is_one_line_break():
    data = b"G1 X1\r\nG1 X2\r\n"
    assert _scan(data, 6)["lines"] == 2  # the pieces end between "\r" and "\n"


def _peak_bytes(lines: int) -> int:
    text = "".join(f"G1 X{k % 100}.{k % 7} Y{k % 37}.5 Z0.2 F1200 ; line {k}\n" for k in range(lines)).encode()
    tracemalloc.start()
    try:
        scan = ProgramScan()
        for k in range(0, len(text), 2**16):
            scan.feed(text[k:k + 2**16])
        assert scan.result()["lines"] == lines
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_lines():
    """The peak of a 20,000-line scan exceeds a 5,000-line one's by at most 32 bytes per extra
    line: the per-line bound a 5,000 against 80,000-line comparison with 1 MiB of slack gives
    (both scans run in many 64 KiB pieces; the peak is ~2.6 MiB whatever the lines, within
    ~50 KB)."""
    small, large = _peak_bytes(5_000), _peak_bytes(20_000)
    assert large - small <= 32 * (20_000 - 5_000), (small, large)
    assert large < 8 * 2**20


@pytest.mark.parametrize("line", ["G1 X" + "9" * 400, "G1 X1e999 Y0"])
def test_a_number_beyond_a_double_is_refused_naming_its_line(line):
    with pytest.raises(InvalidInput) as raised:
        _scan(f"G21\n{line}\n".encode(), 1 << 20)
    assert raised.value.field == "file" and raised.value.value["line"] == 2


def test_a_line_longer_than_a_mib_is_refused_as_it_comes():
    """A program's lines are held whole while read: one of 3 MiB is refused at its second MiB."""
    scan = ProgramScan()
    scan.feed(b"G1 X1\nG1 X2\n")
    with pytest.raises(InvalidInput) as raised:
        for _ in range(48):
            scan.feed(b"G1 X1 " + b"0" * (2**16 - 6))
    assert raised.value.field == "file" and raised.value.value == 3
    assert "line 3 is longer than 1048576 characters" in raised.value.message
    assert scan.size <= 2**20 + 2**17
