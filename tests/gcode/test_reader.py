"""The one G-code reader: modal semantics against hand-computed answers, arcs against the
analytic circle, and a reference slicer's own file against the figures it wrote into it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.gcode.estimator import estimate_gcode
from app.gcode.reader import ARC_CCW, ARC_CW, FEED, HOME, RAPID, GcodeReadError, ReadOptions, read_program
from app.jobs.gcode_meta import gcode_meta
from app.viewer.gcode_paths import parse_toolpath

DATA = Path(__file__).parent / "data"


def test_absolute_relative_and_inch_moves():
    p = read_program("G21 G90\nG1 X10 Y5 F600\nG91\nG1 X1 Y-1\nG20\nG1 X1\nG90\nG1 X0.5\n")
    np.testing.assert_allclose(p.end[:, :3], [[10, 5, 0], [11, 4, 0], [36.4, 4, 0], [12.7, 4, 0]])
    assert p.feed_mm_s[0] == pytest.approx(10.0)
    assert list(p.line) == [2, 4, 6, 8]


def test_motion_is_modal_and_a_line_without_motion_mode_is_ignored():
    p = read_program("X5\nG0 X1 Y1\nX2\nG1 X3 F60\nY4\n")
    assert list(p.motion) == [RAPID, RAPID, FEED, FEED]
    np.testing.assert_allclose(p.end[:, :2], [[1, 1], [2, 1], [3, 1], [3, 4]])


def test_g92_shifts_the_program_frame_not_the_machine():
    p = read_program("G1 X10 F600\nG92 X0\nG1 X5\nG92 E0\nG1 E2\nG92 E0\nG1 X6 E1\n")
    # machine X: 10, then "X5" in a frame shifted by 10 -> 15, then 16
    np.testing.assert_allclose(p.end[:, 0], [10, 15, 15, 16])
    # E machine position accumulates across G92 E0 resets: net extrusion 3 mm
    assert p.end[-1, 3] - p.start[0, 3] == pytest.approx(3.0)
    assert p.count == 4  # G92 is not a move


def test_g28_homes_named_axes_and_clears_their_shift():
    p = read_program("G1 X10 Y10 Z5 F600\nG92 X0\nG28 X\nG1 X1\nG28\n")
    assert list(p.motion) == [FEED, HOME, FEED, HOME]
    np.testing.assert_allclose(p.end[1, :3], [0, 10, 5])
    np.testing.assert_allclose(p.end[2, :3], [1, 10, 5])   # the X shift was cleared by homing
    np.testing.assert_allclose(p.end[3, :3], [0, 0, 0])
    assert p.stop_before[2]


def test_dwell_is_a_stop_and_counts_its_time():
    p = read_program("G1 X10 F600\nG4 P250\nG4 S1\nG1 X20\n")
    assert p.dwell_s == pytest.approx(1.25) and list(p.stop_before) == [False, True]
    assert estimate_gcode("G1 X10 F600\nG4 P250\nG1 X20\n").dwell_s == pytest.approx(0.25)


def test_comments_line_numbers_and_checksums_are_ignored():
    p = read_program("N10 G1 X1 F60*33\n(setup) G1 Y2 ; to Y2\ng1 x3\n")
    np.testing.assert_allclose(p.end[:, :2], [[1, 0], [1, 2], [3, 2]])


@pytest.mark.parametrize("radius", [2.0, 25.0])
def test_ccw_arc_chords_lie_on_the_circle_within_the_tolerance(radius):
    tol = 0.001
    text = f"G1 X{radius} Y0 F600\nG3 X0 Y{radius} I{-radius} J0 Z1 E2\n"
    p = read_program(text, ReadOptions(arc_tolerance_mm=tol))
    arc = p.motion == ARC_CCW
    pts = np.vstack([p.start[arc][:1], p.end[arc]])
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), radius, atol=1e-9)
    mids = 0.5 * (p.start[arc] + p.end[arc])
    sagitta = radius - np.hypot(mids[:, 0], mids[:, 1])
    assert sagitta.max() <= tol * (1 + 1e-9) and sagitta.max() > tol / 4     # not over-split
    angles = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))
    assert np.all(np.diff(angles) > 0) and angles[-1] == pytest.approx(math.pi / 2)   # counter-clockwise
    np.testing.assert_allclose(pts[:, 2], pts[:, 3] / 2)                   # helical Z, linear E, in step
    assert p.end[-1, 2] == pytest.approx(1.0) and p.end[-1, 3] == pytest.approx(2.0)


def test_cw_arc_by_radius_and_full_circle():
    # G2 with R from (0,0) to (10,0), R=5: a clockwise half circle through (5, 5)
    p = read_program("G2 X10 Y0 R5 F600\n", ReadOptions(arc_tolerance_mm=1e-4))
    assert set(p.motion) == {ARC_CW}
    assert p.end[:, 1].max() == pytest.approx(5.0, abs=1e-4)
    # a negative R takes the long way; a full circle (same end point) with I J is 360 degrees
    full = read_program("G1 X10 F600\nG3 X10 Y0 I-10 J0\n", ReadOptions(arc_tolerance_mm=1e-3))
    chords = full.end[full.motion == ARC_CCW] - full.start[full.motion == ARC_CCW]
    assert np.linalg.norm(chords[:, :2], axis=1).sum() == pytest.approx(2 * math.pi * 10, rel=1e-4)


def test_malformed_arcs_and_planes_are_refused_with_the_line():
    for text in ("G2 X10 Y0 R2\n", "G3 X10 Y0\n", "G1 X0\nG3 X10 Y0 I3 J0\n", "G18\nG2 X1 Z1 I1 K0\n"):
        with pytest.raises(GcodeReadError) as info:
            read_program(text)
        assert info.value.field == "gcode" and isinstance(info.value.value, int)


def test_dispense_words_and_profile_lines():
    p = read_program("G1 X1 F60\nM106 S255\nG1 X2\nG0 X3\nM107\nG1 X4\n")
    assert list(p.dispense) == [False, True, False, False]
    exact = read_program("G1 X1 F60\nM64 P0\nG1 X2\nM65 P0\nG1 X3\n",
                         ReadOptions(dispense_on="m64  p0", dispense_off="M65 P0"))
    assert list(exact.dispense) == [False, True, False]
    # an on word at duty 0 switches the output off (Marlin's M106 S0 is its fan off; grbl's M3 S0 no PWM)
    zero = read_program("M106 S255\nG1 X1 F60\nM106 S0\nG1 X2\nM3 S1000\nG1 X3\nM3 S0\nG1 X4\nM8\nG1 X5\n")
    assert list(zero.dispense) == [True, False, True, False, True]


def test_viewer_estimator_and_metadata_read_g92_and_g28_alike():
    text = "G28\nG1 X10 Y0 Z1 F1200\nG92 X0 Y0\nG1 X5 Y5 E1\nG91\nG1 X1 Y1 E1\nG90\nG28 X\n"
    program = read_program(text)
    segments = parse_toolpath(text)
    np.testing.assert_allclose(segments.ends[-2], [16, 6, 1])     # machine frame, after G92 and G91
    assert gcode_meta(text)["bounds"] == [[10.0, 0.0, 1.0], [16.0, 6.0, 1.0]]   # homing excluded
    assert estimate_gcode(text).moves == program.count


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=1, max_size=12),
       st.floats(-20, 20))
def test_relative_moves_sum_to_the_absolute_end_after_any_g92(steps, shift):
    """Property: G91 steps from a G92-declared origin end where their sum says, in the
    machine frame, whatever the declared coordinate."""
    text = "G1 X7 F600\n" + f"G92 X{shift:.6f}\nG91\n" + "".join(f"G1 X{dx:.6f} Y{dy:.6f}\n" for dx, dy in steps)
    end = read_program(text).end[-1]
    assert end[0] == pytest.approx(7 + sum(round(dx, 6) for dx, _ in steps), abs=1e-6)
    assert end[1] == pytest.approx(sum(round(dy, 6) for _, dy in steps), abs=1e-6)


def test_prusaslicer_file_reads_as_prusaslicer_describes_it():
    """PrusaSlicer 2.5's own G-code (a 6 mm radius, 3 mm cylinder, 0.3 mm layers, 30 %
    infill) against the figures PrusaSlicer wrote into it: filament used, layer heights,
    and its own time estimate."""
    text = (DATA / "prusaslicer_2.5_cylinder_r6_h3.gcode").read_text()
    program = read_program(text)
    # PrusaSlicer counts the filament pushed out while moving (not retractions/unretractions)
    advance = program.end[:, 3] - program.start[:, 3]
    moving = np.linalg.norm(program.end[:, :3] - program.start[:, :3], axis=1) > 0
    assert advance[moving & (advance > 0)].sum() == pytest.approx(119.42, abs=0.01)   # "filament used [mm] = 119.42"
    retracts = advance[~moving & (advance < 0)]
    np.testing.assert_allclose(retracts, -2.0)                                        # "retract_length = 2"
    layers = np.unique(np.round(program.end[program.dispense, 2], 6))
    np.testing.assert_allclose(layers, np.arange(1, 11) * 0.3, atol=1e-9)  # ten 0.3 mm layers
    # every printing move lies on the part or its skirt (6 mm out, one line): within 6 + 6 + 1 mm
    centre = np.array([100.0, 100.0])                                        # bed_shape 200 x 200
    assert np.hypot(*(program.end[program.dispense, :2] - centre).T).max() < 13.0
    # our planner vs PrusaSlicer's own estimate ("normal mode = 2m 4s"), different models: within 10 %
    assert estimate_gcode(text).total_s == pytest.approx(124.0, rel=0.10)
    assert (program.home.sum() == 2
            and gcode_meta(text)["bounds"][1][2] == pytest.approx(program.end[~program.home, 2].max()))
