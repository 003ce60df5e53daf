"""Tests for app.gcode.writer: header, number formatting, dialect table, bad input."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.domain.errors import InvalidInput
from app.gcode.writer import DEFAULT_DIALECT, DIALECT_NAMES, DIALECTS, GcodeError, ProgramBuilder, format_number
from hardware import dialects as host


def test_header_and_units():
    text = ProgramBuilder("grbl", "probe_plan", "j42").text()
    assert text.splitlines() == ["; conforma job=j42 kind=probe_plan units=mm", "G21", "G90"]
    assert text.endswith("\n") and not text.endswith("\n\n")
    assert ProgramBuilder("marlin", "print").lines[0] == "; conforma job=- kind=print units=mm"


def test_moves_fixed_decimals_and_no_negative_zero():
    b = ProgramBuilder("marlin", "print", "a", decimals=4)
    b.rapid(z=5).move(x=-0.00001, y=1.23456789, z=-2, feed_mm_min=1200, e=0.5)
    assert b.lines[-2:] == ("G0 Z5.0000", "G1 X0.0000 Y1.2346 Z-2.0000 E0.5000 F1200.0")
    assert "-0.0000" not in b.text()


@settings(max_examples=60)
@given(st.floats(min_value=-1e4, max_value=1e4, allow_nan=False), st.integers(0, 6))
def test_format_number_round_trip(value, decimals):
    text = format_number(value, decimals)
    assert abs(float(text) - value) <= 0.5 * 10 ** -decimals + 1e-9
    assert not (text.startswith("-") and float(text) == 0.0)
    assert len(text.split(".")[1]) == decimals if decimals else "." not in text


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_coordinates_rejected(bad):
    with pytest.raises(GcodeError) as info:
        ProgramBuilder("grbl", "k").move(x=bad)
    assert isinstance(info.value, InvalidInput) and info.value.field == "x"


def test_probe_commands_per_dialect():
    g = ProgramBuilder("grbl", "probe_plan").probe("g38", z=-1.5, feed_mm_min=100)
    assert g.lines[-1] == "G38.2 Z-1.5000 F100.0"
    m = ProgramBuilder("marlin", "probe_plan").probe("g30", x=10, y=20)
    assert m.lines[-1] == "G30 X10.0000 Y20.0000"
    ProgramBuilder("marlin", "probe_plan").probe("g38", z=0, feed_mm_min=50)
    with pytest.raises(GcodeError):
        ProgramBuilder("grbl", "probe_plan").probe("g30", x=0, y=0)
    assert set(DIALECTS) == {"grbl", "marlin", "linuxcnc"}
    lc = ProgramBuilder("linuxcnc", "probe_plan").probe("g38", z=-2, feed_mm_min=100).end()
    assert lc.lines[-2:] == ("G38.2 Z-2.0000 F100.0", "M2")  # LinuxCNC needs a program end
    with pytest.raises(GcodeError):
        ProgramBuilder("linuxcnc", "probe_plan").probe("g30", x=0, y=0)


def test_bad_inputs_are_typed():
    with pytest.raises(GcodeError):
        ProgramBuilder("fanuc", "k")
    with pytest.raises(GcodeError):
        ProgramBuilder("grbl", "two words")
    with pytest.raises(GcodeError):
        ProgramBuilder("grbl", "k").move()
    with pytest.raises(GcodeError):
        ProgramBuilder("grbl", "k").move(x=1, feed_mm_min=0)
    with pytest.raises(GcodeError):
        ProgramBuilder("grbl", "k").move(x=1, q=2)
    with pytest.raises(GcodeError):
        ProgramBuilder("grbl", "k").raw("G0 X1\nG0 X2")


def test_comment_is_one_line_and_end_markers():
    b = ProgramBuilder("grbl", "k").comment("a (b)\nc").wait_for_moves().end()
    assert b.lines[-3:] == ("; a [b] c", "G4 P0", "M2")
    assert ProgramBuilder("marlin", "k").wait_for_moves().end().lines[-1] == "M400"


def test_identical_inputs_identical_bytes():
    def build():
        return ProgramBuilder("marlin", "k", "x").rapid(x=1, y=2).move(z=0.1, feed_mm_min=60).text()
    assert build() == build()


def test_the_builders_bounds_are_what_the_reader_reads_and_none_when_it_cannot_follow():
    from app.compensation.standoff import CompensationParams, _program
    from app.gcode.reader import read_program
    from app.jobs.gcode_meta import gcode_meta

    rng = np.random.default_rng(5)
    points = np.cumsum(rng.normal(0.0, 1.3, (60, 3)), axis=0) + [10.0, -20.0, 3.0]
    for dialect, tool, dwell in (("marlin", None, 0.0), ("grbl", 2, 0.5), ("marlin", 1, 0.2)):
        params = CompensationParams(standoff_mm=0.1, dialect=dialect, tool=tool, dwell_s=dwell,
                                    tool_offset_mm=(1.25, -3.5, 0.75) if tool else (0.0, 0.0, 0.0))
        text, bounds = _program(points, params, "job_x", ["a note"])
        assert bounds == read_program(text).bounds().tolist()  # the reader's numbers, exactly
        assert gcode_meta(text, bounds=bounds) == gcode_meta(text)
    moving = CompensationParams(standoff_mm=0.1, dispense_on="G1 Z9", dispense_off="M107")
    assert _program(points, moving, None, [])[1] is None  # a dispense command that moves: not followed
    b = ProgramBuilder("grbl", "probe_plan")
    b.rapid(z=5.0).rapid(x=1.0, y=2.0)
    assert b.bounds() == [[0.0, 0.0, 5.0], [1.0, 2.0, 5.0]]  # from 0, 0, 0 as the reader starts
    b.probe("g38", z=-1.0, feed_mm_min=100.0)
    assert b.bounds() is None  # where a probe stops is the part's business
    assert ProgramBuilder("grbl", "x").bounds() is None  # no moves


def test_the_hardware_serves_the_writers_dialects_with_the_same_default():
    """A machine's dialect is one of the writer's (``DialectName``); the serial host drives the
    serial ones, the LinuxCNC backend the rest, and both default to the same dialect."""
    assert set(host.DIALECTS) | {"linuxcnc"} == set(DIALECT_NAMES) and host.DEFAULT_DIALECT == DEFAULT_DIALECT


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(*[st.one_of(st.floats(-1e4, 1e4), st.sampled_from([-0.0, -0.00004, 0.00005, -0.00005,
                                                                               1.00005, -2.5e-5, 12.34565])),
                            ] * 3), min_size=1, max_size=40),
       st.integers(0, 6), st.one_of(st.none(), st.floats(1.0, 6000.0)))
def test_moves_made_at_once_are_the_moves_made_one_by_one(points, decimals, feed):
    """extend_moves writes the text, bounds and recorded program k calls of move write."""
    one = ProgramBuilder("marlin", "compensate", "j1", decimals=decimals, record=True).rapid(z=5.0)
    many = ProgramBuilder("marlin", "compensate", "j1", decimals=decimals, record=True).rapid(z=5.0)
    for i, (x, y, z) in enumerate(points):
        one.move(x=x, y=y, z=z, feed_mm_min=feed if i == 0 else None)
    many.extend_moves(np.array(points), feed)
    assert many.text() == one.text()
    assert many.bounds() == one.bounds()
    mine, theirs = many.program(), one.program()
    for name in ("start", "end", "feed_mm_s", "motion", "line"):
        assert np.array_equal(getattr(mine, name), getattr(theirs, name), equal_nan=name != "motion"), name


def test_moves_made_at_once_refuse_a_non_finite_coordinate_and_write_nothing():
    b = ProgramBuilder("grbl", "compensate", "j1")
    before = b.text()
    with pytest.raises(GcodeError) as err:
        b.extend_moves(np.array([[0.0, 1.0, 2.0], [1.0, math.nan, 2.0]]), 300.0)
    assert err.value.field == "y" and b.text() == before
    assert b.extend_moves(np.zeros((0, 3)), 300.0).text() == before
