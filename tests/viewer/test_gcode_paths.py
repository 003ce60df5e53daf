"""G-code -> segments for the view: dispense vs travel, units, modes, rotary words."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.gcode.writer import ProgramBuilder
from app.viewer.gcode_paths import GcodeViewError, parse_toolpath


def test_dispense_between_default_on_and_off_words():
    text = "G21\nG90\nG0 X1 Y1 Z1\nM106 S255\nG1 X2 F300\nG1 Y2\nM107\nG1 X0 Y0\nG0 Z5\n"
    seg = parse_toolpath(text)
    assert seg.count == 5
    assert seg.dispense.tolist() == [False, True, True, False, False]
    assert np.allclose(seg.starts[1], [1, 1, 1]) and np.allclose(seg.ends[1], [2, 1, 1])
    assert np.allclose(seg.ends[2], [2, 2, 1])


def test_explicit_profile_lines_replace_the_default_words():
    text = "G1 X1\nM42 P6 S255\nG1 X2\nM106\nG1 X3\nM42 P6 S0\nG1 X4\n"
    seg = parse_toolpath(text, dispense_on="M42 P6 S255", dispense_off="M42 P6 S0")
    assert seg.dispense.tolist() == [False, True, True, False]  # M106 is an ordinary line here


def test_extrusion_counts_as_dispensing_absolute_and_relative():
    absolute = "M82\nG92 E0\nG1 X10 E1\nG1 X20 E1\nG1 E0.2\nG1 X30 E2\n"
    assert parse_toolpath(absolute).dispense.tolist() == [True, False, True]  # retract-only move has no xyz
    relative = "M83\nG1 X10 E0.5\nG1 X20 E0\nG1 X30 E-0.1\nG1 X40 E0.3\n"
    assert parse_toolpath(relative).dispense.tolist() == [True, False, False, True]


def test_relative_moves_inches_comments_line_numbers_and_layers():
    text = ("N1 G20*12\n(inches from here) G91 ; relative\n;LAYER:3\nG0 X1 Y0\nG1 X1 (comment) Y1\n"
            "N5 G21 G90*99\n;LAYER:4\nG1 X0 Y0 Z0\n")
    seg = parse_toolpath(text)
    assert np.allclose(seg.ends[0], [25.4, 0, 0])
    assert np.allclose(seg.ends[1], [50.8, 25.4, 0])
    assert np.allclose(seg.ends[2], [0, 0, 0])
    assert seg.layer.tolist() == [3, 3, 4]


def test_rotary_words_are_carried_per_segment():
    seg = parse_toolpath("G1 X1 A10 C-20 F100\nG1 A15\nG1 X2 C5\n")
    assert seg.a_deg.tolist() == [10, 15, 15] and seg.c_deg.tolist() == [-20, -20, 5]
    assert seg.has_rotary


@pytest.mark.parametrize("text", [b"\xff\xfe\x00", "G21\nG90\nM2\n", ""])
def test_no_moves_or_not_text_is_a_clear_error(text):
    with pytest.raises(GcodeViewError) as info:
        parse_toolpath(text)
    assert info.value.field == "gcode"


coords = st.floats(-200, 200, allow_nan=False).map(lambda v: round(v, 4))


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(coords, coords, coords, st.booleans()), min_size=1, max_size=30))
def test_programs_from_the_builder_round_trip(moves):
    """What ProgramBuilder writes comes back as the same segments (to 4 decimals)."""
    b = ProgramBuilder("marlin", "test", "job_x")
    expected_dispense = []
    pos = np.zeros(3)
    ends = []
    for x, y, z, dispense in moves:
        b.raw("M106" if dispense else "M107")
        b.move(x=x, y=y, z=z, feed_mm_min=600.0)
        if not np.allclose([x, y, z], pos):
            expected_dispense.append(dispense)
            ends.append([x, y, z])
        pos = np.array([x, y, z])
    if not ends:
        return
    seg = parse_toolpath(b.text())
    assert np.allclose(seg.ends, ends, atol=1e-4)
    assert seg.dispense.tolist() == expected_dispense
