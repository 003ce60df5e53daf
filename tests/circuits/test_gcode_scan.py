"""The warp's two G-code readers agree: the vectorised one (plain G0/G1 programs) gives the
same records, bit for bit, as the line-by-line one on programs using every modal feature;
programs it does not read (arcs, G92, exponents, parenthesised comments) go line by line."""

from __future__ import annotations

import numpy as np
import pytest

from app.circuits.errors import WarpError
from app.circuits.gcode_scan import PRINT, TRAVEL, _scan_fast, scan_lines, scan_program

MODAL = """; every modal feature the vectorised reader takes
G21
G90
M82
G1 X1 Y1 F100
G91
G1 X0.1 Y0.2 E0.3
g1 x.5 E+0.1 ; lower case, a signed number (and a comment)
G90 G20
G1 X1 Y2 E2

G0 X2 Y2
G1 E3
M106 M107
G1 X3 Y3
M3
G1 X4 Y4
G1 Z3
G21 G91
G1 X-1 E0.5
M83
G1 X-1 E0.5 F0
G1 F300
G1 X1
T0
M104 S200
G17
G90
G1 X10 Y10 Z1
G1 X10 Y10
G1 X0.1 Y0.2
G91
G1 X0.1 Y0.2 E0.1
G1 X0.1 Y0.2 E0.1
G90
G1 X0.3 Y0.3
N7 G1 X5 Y5 E1
G0X6Y6
M9 M8
G1 X7 Y7 F1200.5
"""


def _same(a, b) -> None:
    assert np.array_equal(a.kind, b.kind) and np.array_equal(a.line, b.line) and np.array_equal(a.e_abs, b.e_abs)
    for name in ("start", "end", "feed"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert a.lines == b.lines


@pytest.mark.parametrize("text", [MODAL, MODAL.replace("\n", "\r\n"), MODAL.rstrip("\n"), "G1 X1 Y1 E1\n", "",
                                  "; only a comment\n", "\n\n", "G21\nG0 X1 Y1\n"])
def test_the_vectorised_reader_gives_the_line_readers_records(text):
    fast = _scan_fast(text)
    assert fast is not None
    _same(fast, scan_lines(text))


def test_the_modal_program_is_read_as_the_rules_say():
    recs = _scan_fast(MODAL)
    kinds = {int(recs.line[i]) + 1: int(recs.kind[i]) for i in range(len(recs.kind))}
    assert kinds[5] == TRAVEL                          # G1 without E, not dispensing
    assert kinds[7] == PRINT and kinds[15] == TRAVEL   # M106 M107 on one line: stopped
    assert kinds[17] == PRINT                          # dispensing after M3
    i = int(np.flatnonzero(recs.line == 9)[0])          # "G1 X1 Y2 E2" after G20: inches
    assert recs.end[i, :2].tolist() == [25.4, 50.8]
    assert recs.feed[i] == 100.0
    i = int(np.flatnonzero(recs.line == 7)[0])          # x.5 relative (G91); E absolute (M82)
    assert recs.end[i, 0] == pytest.approx(1.6) and recs.end[i, 3] == pytest.approx(0.1)


@pytest.mark.parametrize("text", [
    "G1 X1 Y1 E1\nG2 X2 Y2 I0.5 J0.5 E2\n",          # an arc
    "G1 X1 Y1E1e0\n",                                  # an exponent
    "G1 X1 (a comment) Y1 E1\n",                       # a parenthesised comment
    "G1 X1 Y1 E1*57\n",                                # a checksum
    "M117 hello\nG1 X1 Y1 E1\n",                       # text a plain reader cannot take
])
def test_other_programs_go_line_by_line(text):
    assert _scan_fast(text) is None
    try:
        expected = scan_lines(text)
    except Exception as exc:                           # noqa: BLE001 - the same refusal either way
        with pytest.raises(type(exc)):
            scan_program(text)
        return
    _same(scan_program(text), expected)


def test_g92_is_refused_naming_its_line():
    with pytest.raises(WarpError) as err:
        scan_program("G1 X1 Y1 E1\nG92 E0\n")
    assert err.value.value["line"] == 2


def test_programs_without_printing_moves_are_warped_too():
    from app.circuits.heightfield import HeightField
    from app.circuits.warp import warp_program

    x = np.linspace(0, 10, 5)
    out = warp_program("; nothing\nG21\nG0 X1 Y1\n", HeightField(x, x, np.zeros((5, 5))))
    assert out.pieces == 0 and out.text.splitlines()[-2:] == ["G0 Z2", "G0 X1 Y1"]
