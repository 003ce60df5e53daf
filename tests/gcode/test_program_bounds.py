"""A program's bounds read by arrays, block by block, equal the modal reader's line by line
bit for bit (and its refusals word for word), whatever the blocks; an arc's extent is exact:
its circle's axis crossings, never below dense chords and within their sagitta of them; a
full circle of any radius costs the same."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.domain.errors import InvalidInput
from app.gcode.lines import iter_lines
from app.gcode.program_bounds import BoundsScan, LineBounds
from app.gcode.reader import ReadOptions, read_program
from app.jobs.gcode_meta import ProgramScan
from hardware.protocol import normalize_block, normalize_command

_NUM = st.one_of(st.integers(-500, 500).map(str), st.floats(-500, 500, allow_nan=False).map(lambda v: f"{v:.3f}"),
                 st.sampled_from([".5", "-.25", "+2", "7.", "-0"]))
_MOVE = st.builds(lambda g, words: f"{g}{' '.join(words)}",
                  st.sampled_from(["G1 ", "G0 ", "", "g1 ", "G01 ", "G1", "N7 G1 "]),
                  st.lists(st.builds(lambda a, v: f"{a}{v}", st.sampled_from("XYZEXYF"), _NUM), min_size=1, max_size=4))
_ARC = st.builds(lambda g, i, j, e: f"{g} I{i} J{j} E{e}", st.sampled_from(["G2", "G3"]), _NUM, _NUM, _NUM)
_ODD_ARC = st.builds(lambda g, x, r: f"{g} X{x} Y{x} R{r}", st.sampled_from(["G2", "G3"]), _NUM, _NUM)
_OTHER = st.sampled_from(["G90", "G91", "G20", "G21", "M82", "M83", "G92 X1 Y-2", "G92 E0", "G28", "G28 X", "G4 P10",
                          "G91 G4 P1", "M104 S200", "M92 X80", "; comment G1 X900", "(paren) G1 X3", "N10 G1 X1 Y1*45",
                          "%", "M117 hello world", "", "G17", "G1 A5", "G1 X1E2", "G1 X1 Y2 ; tail", "M106 G1 X2",
                          "G1 X" + "9" * 400, "  G1\tX-3  ", "G54", "G1 X1.2.3", "T0", "M201 X500", "n3 G1 X2",
                          "\tM82", " N4 G1 X1"])
_LINE = st.one_of(_MOVE, _MOVE, _MOVE, _ARC, _ODD_ARC, _OTHER)


def _by_line(text: str) -> object:
    reader = LineBounds("file")
    try:
        for parsed in iter_lines(text, strict=False):
            reader.line(parsed)
    except InvalidInput as exc:
        return (type(exc).__name__, exc.message, exc.field, exc.value)
    return reader.bounds()


def _by_blocks(text: str, cuts: list[int]) -> object:
    lines = text.split("\n")
    scan, first = BoundsScan("file"), 1
    try:
        for a, b in zip([0, *cuts], [*cuts, len(lines)]):
            scan.block("".join(line + "\n" for line in lines[a:b]), first)
            first += b - a
    except InvalidInput as exc:
        return (type(exc).__name__, exc.message, exc.field, exc.value)
    return scan.bounds()


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_LINE, min_size=1, max_size=120), st.lists(st.integers(0, 120), max_size=4))
def test_blocks_read_by_arrays_agree_with_the_reader_line_by_line(lines, cuts):
    text = "\n".join(lines)
    cuts = sorted({c for c in cuts if 0 < c < len(lines)})
    assert _by_blocks(text, cuts) == _by_line(text)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(["G1 X1 Y2", "  G1 X1 ", "\tG1", "N10 G1 X1*77", "n-3 G0 Z1 * 12 ", "G1 (c) X2",
                                 "G1 ; c", "(only)", ";only", "", " ", "N5", "G1 (a;b) X2", "G1 *", "G1 X1*7a",
                                 "((x)y)", "G1 X1 ( open", "M117 a  b", "%", "N1 N2 G1"]), max_size=30),
       st.booleans())
def test_a_block_normalises_as_its_lines_do(lines, newline_at_end):
    text = "\n".join(lines) + ("\n" if newline_at_end else "")
    expected = "".join(c + "\n" for line in text.split("\n") if (c := normalize_command(line)) is not None)
    assert normalize_block(text) == expected


def test_a_program_scans_alike_by_blocks_and_line_by_line():
    """The same facts whether the text goes through the arrays or line by line (non-ASCII)."""
    body = "".join(f"G1 X{k % 17}.5 Y{k % 5} ; c\nG2 X{k % 17}.5 Y{k % 5} I1 J0\nG92 E0\n" for k in range(2_000))
    fast, slow = ProgramScan(), ProgramScan()
    fast.feed(body.encode())
    slow.feed(("; é\n" + body).encode())
    a, b = fast.result(), slow.result()
    assert a["bounds"] == b["bounds"] == [[0.5, -1.0, 0.0], [18.5, 5.0, 0.0]]  # full circles of radius 1
    assert (a["commands"], a["commands_sha256"]) == (b["commands"], b["commands_sha256"])
    assert a["lines"] + 1 == b["lines"] == 6_001


@settings(max_examples=200, deadline=None)
@given(st.floats(-100, 100), st.floats(-100, 100), st.floats(0.01, 1000), st.floats(-math.pi, math.pi),
       st.floats(0.01, 2 * math.pi), st.booleans(), st.floats(-5, 5))
def test_an_arcs_exact_extent_bounds_its_dense_chords_within_their_sagitta(cx, cy, r, a0, sweep, clockwise, dz):
    a1 = a0 - sweep if clockwise else a0 + sweep
    sx, sy = cx + r * math.cos(a0), cy + r * math.sin(a0)
    ex, ey = cx + r * math.cos(a1), cy + r * math.sin(a1)
    text = (f"G0 X{sx:.17g} Y{sy:.17g} Z0\n{'G2' if clockwise else 'G3'} X{ex:.17g} Y{ey:.17g} Z{dz:.17g} "
            f"I{cx - sx:.17g} J{cy - sy:.17g}\n")
    tol = max(r * 1e-7, 1e-6)
    dense = read_program(text, ReadOptions(arc_tolerance_mm=tol)).bounds()
    exact = BoundsScan()
    exact.block(text, 1)
    low, high = np.array(exact.bounds())
    slack = 1e-9 * (1 + r + abs(cx) + abs(cy))
    assert (low <= dense[0] + slack).all() and (high >= dense[1] - slack).all()
    assert (dense[0] - low <= tol + slack).all() and (high - dense[1] <= tol + slack).all()


@pytest.mark.parametrize("radius", [1, 1_000, 1_000_000_000])
def test_full_circles_of_any_radius_have_exact_bounds_at_no_cost(radius):
    text = "G21\nG90\nG0 X10 Y10\n" + f"G2 X10 Y10 I{radius} J0 F600\n" * 4 + f"G3 X10 Y10 I0 J-{radius}\n"
    cpu = time.process_time()
    scan = ProgramScan()
    scan.feed(text.encode())
    meta = scan.result()
    assert time.process_time() - cpu < 0.5
    # the circles around (10 + r, 10) and (10, 10 - r)
    assert meta["bounds"] == [[10.0 - radius, 10.0 - 2 * radius, 0.0], [10.0 + 2 * radius, 10.0 + radius, 0.0]]


def test_an_arc_that_is_not_one_is_refused_naming_its_line_and_the_field():
    scan = ProgramScan(field="file")
    with pytest.raises(InvalidInput) as raised:
        scan.feed(b"G0 X0 Y0\nG1 X1\nG2 X5 Y0 I1 J0\n")
        scan.result()
    assert raised.value.field == "file" and raised.value.value == 3
    assert "line 3: arc end is not on its circle" in raised.value.message


def test_arc_chords_are_counted_as_the_reader_makes_them_and_refused_beyond_the_budget():
    from app.gcode.reader import ModalReader

    text = "G21\nG90\nG0 X10 Y10\n" + "".join(f"G2 X10 Y10 I{r} J0\nG3 X{10 + 2 * r} Y10 R{r}\nG2 X10 Y10 R-{r}\n"
                                                 for r in (0.5, 3, 40, 700))
    reader = ModalReader(ReadOptions(arc_tolerance_mm=1e-3))
    for parsed in iter_lines(text):
        reader.line(parsed)
    counted = BoundsScan(arc_chord_mm=1e-3)
    counted.block(text, 1)
    assert counted.chords == reader.chords > 1_000
    cpu = time.process_time()
    refused = BoundsScan(arc_chord_mm=1e-4, max_arc_chords=10_260)
    with pytest.raises(InvalidInput) as raised:
        refused.block("G21\nG90\nG0 X10 Y10\n" + "G2 X10 Y10 I1000000 J0 F600\n" * 4, 1)
    assert time.process_time() - cpu < 0.1                  # 222,000 chords a circle: counted, none made
    assert raised.value.field == "arc_chord_mm" and raised.value.value == {"line": 4, "max_chords": 10_260}
