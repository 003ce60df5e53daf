"""The warp's two passes agree: the vectorised one (plain G0/G1 programs, with comments, line
numbers, tape marks and modal motion) gives the same records, bit for bit, as the one G-code
reader line by line; programs it does not read (arcs, G92, G28, exponents, checksums) go line
by line; what the warp does not model is refused naming the line."""

from __future__ import annotations

import numpy as np
import pytest

from app.circuits.errors import WarpError
from app.circuits.gcode_scan import MODE, PRINT, TRAVEL, _scan_fast, scan_lines, scan_program

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
    assert a.lines == b.lines and a.carried == b.carried and np.array_equal(a.motion, b.motion)


POSTS = """%
(a post's header comment)
N10 G21 G90 G94 G17 G40 G49 G80
N20 G0 Z5.
N30 M3 S1000
N40 G0 X1. Y2.
N50 Z0.5
N60 G1 Z-0.05 F60.
N70 X3. (modal G1) F150.
N80 Y4.
N90 Y4.
N100 G0 Z1.
N110 G0 Z1.
N120 G91 G0 Z2.
N130 G90
N140 M5
%
"""


@pytest.mark.parametrize("text", [MODAL, MODAL.replace("\n", "\r\n"), MODAL.rstrip("\n"), "G1 X1 Y1 E1\n", "",
                                  "; only a comment\n", "\n\n", "G21\nG0 X1 Y1\n", POSTS,
                                  "(comment first)\n" + MODAL, "G1 X1 (a comment) Y1 E1\n",
                                  "G0 X1 Y1 M8\nG1 X2 Y2 S100\n",
                                  "M106 S255\nG1 X1 Y1 F60\nM106 S0\nG1 X2 Y2\nM3 S0\nG1 X3 Y3\nM3 S9\nG1 X4 Y4\n"])
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
    # x.5 relative (G91); E relative too under G91 (the reader's rule), whatever M82 says
    assert recs.end[i, 0] == pytest.approx(1.6) and recs.end[i, 3] == pytest.approx(0.4)


@pytest.mark.parametrize("text", [
    "G1 X1 Y1 E1\nG2 X2 Y2 I0.5 J0.5 E2\n",          # an arc
    "G1 X1 Y1E1e0\n",                                  # an exponent
    "G28 G91 Z0\nG90\nG0 X1 Y1\n",                        # homing
    "G1 X1 2\n", "G1 X\n", "G1 X1-2\n", "1 G1 X1\n", "G1 X1.2.3\n", "G1 X\n1\n", "G1 X+\n",  # not words
    "G1 X1\x0bY1\n", "G1 X1 ; caf\u00e9\n",               # a line break splitlines() sees, not ASCII
    "G92 X1\nG0 X2 Y1\n",                               # a shift
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


def test_g92_shifts_the_program_frame_and_the_records_stay_in_machine_coordinates():
    recs = scan_program("G1 X1 Y1 E1\nG92 X0 Y0\nG1 X1 Y1 E2\n")
    assert recs.kind.tolist() == [PRINT, MODE, PRINT]
    assert recs.end[2, :2].tolist() == [2.0, 2.0]


@pytest.mark.parametrize("line, why", [
    ("G43 H1 Z15", "G43"), ("G53 G0 Z0", "G53"), ("G81 X1 Y1 Z-1 R1", "G81"), ("G1 X1 A90", "A"),
    ("G38.2 Z-5 F50", "G38.2"), ("G1 X1 Y1 G4 P1", "G4"), ("G1 X1 Y1 H2", "H"),
])
def test_what_the_warp_does_not_model_is_refused_naming_the_line(line, why):
    with pytest.raises(WarpError, match=f"line 2: .*{why}") as err:
        scan_program(f"G21\n{line}\nG0 X2 Y2\n")
    assert err.value.value == {"line": 2, "text": line}


def test_axis_words_before_any_motion_mode_are_refused():
    with pytest.raises(WarpError, match="line 2: axis words before any motion mode"):
        scan_program("G21\nX1 Y1\n")


def test_programs_without_printing_moves_are_warped_too():
    from app.circuits.heightfield import HeightField
    from app.circuits.warp import warp_program

    x = np.linspace(0, 10, 5)
    out = warp_program("; nothing\nG21\nG0 X1 Y1\n", HeightField(x, x, np.zeros((5, 5))))
    assert out.pieces == 0 and out.text.splitlines()[-2:] == ["G0 Z2", "G0 X1 Y1"]
