"""Arcs to chords under a budget: every arc's chords are counted before any is made, the
count is exactly what the reader makes, and a program's arcs may need at most the budget of
its size (a radius of 1e9 mm is refused naming its line, in microseconds)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.gcode.arcs import MIN_ARC_TOLERANCE_MM, arc_chord_counts
from app.gcode.lines import GcodeReadError
from app.gcode.program_bounds import BoundsScan
from app.gcode.reader import (
    ARC_CCW,
    ARC_CHORDS_PER_BYTE,
    ARC_CW,
    MAX_ARC_CHORDS,
    ArcBudgetError,
    ReadOptions,
    arc_chord_budget,
    beyond_size_budget,
    read_program,
)


def _analytic_chords(radius: float, sweep: float, tol: float) -> int:
    """n = ceil(|sweep| / (2 acos(1 - tol / r))): the chords of sagitta tol on an arc of radius r."""
    return math.ceil(abs(sweep) / (2.0 * math.acos(1.0 - tol / radius)))


def test_a_full_circle_is_split_into_the_analytic_number_of_chords():
    program = read_program("G1 X10 Y0 F600\nG2 X10 Y0 I-10 J0\n", ReadOptions(arc_tolerance_mm=0.002))
    chords = int(np.isin(program.motion, (ARC_CW, ARC_CCW)).sum())
    assert chords == _analytic_chords(10.0, 2 * math.pi, 0.002) == 158
    ends = program.end[program.motion == ARC_CW, :2]
    mid = (np.vstack([program.start[program.motion == ARC_CW, :2]]) + ends) / 2.0
    # each chord's sagitta is within the tolerance (the chord's middle is inside the circle by at most tol)
    assert float((10.0 - np.hypot(mid[:, 0], mid[:, 1])).max()) <= 0.002 + 1e-12


arcs = st.tuples(
    st.floats(0.05, 1e4),                       # radius mm
    st.floats(-math.pi, math.pi),               # start angle rad
    st.floats(1e-3, 2 * math.pi - 1e-3),        # swept angle rad (less than a turn)
    st.booleans(),                              # clockwise
    st.sampled_from([1e-6, 1e-4, 0.002, 0.05, 1.0]),  # chord tolerance mm
    st.booleans(),                              # centre as I J (else R)
)


@settings(max_examples=150, deadline=None)
@given(arcs)
def test_the_chords_counted_before_reading_are_the_chords_the_reader_makes(arc):
    radius, a0, sweep, clockwise, tol, use_ij = arc
    a1 = a0 - sweep if clockwise else a0 + sweep
    start = np.array([radius * math.cos(a0), radius * math.sin(a0)])
    end = np.array([radius * math.cos(a1), radius * math.sin(a1)])
    if use_ij:
        centre_words = f"I{-start[0]:.6f} J{-start[1]:.6f}"
    else:  # R: negative for the long way round
        centre_words = f"R{radius if sweep <= math.pi else -radius:.6f}"
    text = (f"G1 X{start[0]:.6f} Y{start[1]:.6f} F600\n"
            f"{'G2' if clockwise else 'G3'} X{end[0]:.6f} Y{end[1]:.6f} {centre_words}\n")
    scan = BoundsScan(arc_chord_mm=tol)
    try:
        scan.block(text, 1)
    except ArcBudgetError:
        pass
    except GcodeReadError:  # an R arc whose rounded ends make it no arc: both readers refuse it alike
        with pytest.raises(GcodeReadError):
            read_program(text, ReadOptions(arc_tolerance_mm=tol, max_arc_chords=MAX_ARC_CHORDS))
        return
    predicted = scan.chords
    try:
        program = read_program(text, ReadOptions(arc_tolerance_mm=tol, max_arc_chords=MAX_ARC_CHORDS))
    except ArcBudgetError as exc:
        assert predicted > MAX_ARC_CHORDS and exc.value["chords"] == predicted
        return
    made = int(np.isin(program.motion, (ARC_CW, ARC_CCW)).sum())
    assert made == predicted
    # and the closed form, where the step is not floored (the written ends move the angle by ~1e-6 mm / r)
    if tol < radius and sweep > 1e-2 and 2 * math.acos(1 - tol / radius) > 1e-4:
        assert abs(made - _analytic_chords(radius, sweep, max(tol, MIN_ARC_TOLERANCE_MM))) <= 1


def test_counts_agree_with_the_vectorised_count_at_the_floors():
    # a tolerance below the floor is the floor; an angular step below 1e-6 rad is 1e-6 rad
    r0 = np.array([1e9, 1.0, 1e-7])
    sweep = np.array([2 * math.pi, -math.pi, math.pi / 2])
    counts = arc_chord_counts(r0, sweep, 0.0)
    assert counts.tolist() == [math.ceil(2 * math.pi / 1e-6), _analytic_chords(1.0, math.pi, 1e-6), 1]


def test_a_radius_of_1e9_at_a_tiny_tolerance_is_refused_naming_its_line_before_any_chord():
    text = "G21 G90\nG1 X1e9 Y0 F600\nG2 X1e9 Y0 I-1e9 J0\nG1 X0\n"
    before = time.process_time()
    with pytest.raises(ArcBudgetError) as refused:
        read_program(text, ReadOptions(arc_tolerance_mm=1e-6))
    assert time.process_time() - before < 0.05
    assert refused.value.message.startswith("line 3: ")
    assert refused.value.value["line"] == 3
    assert refused.value.value["max_chords"] == arc_chord_budget(len(text)) == 10_000 + ARC_CHORDS_PER_BYTE * len(text)
    assert refused.value.value["chords"] == math.ceil(2 * math.pi / 1e-6)   # the floor of the angular step


def test_the_default_budget_is_the_programs_size_and_refuses_at_the_exact_line():
    head = "G1 X10 Y0 F600\n"
    circle = "G2 X10 Y0 I-10 J0\n"                  # 158 chords at the default 0.002 mm
    text = head + circle * 1000
    budget = arc_chord_budget(len(text))
    assert budget == 10_000 + ARC_CHORDS_PER_BYTE * len(text)
    with pytest.raises(ArcBudgetError) as refused:
        read_program(text)
    first_over = budget // 158 + 1                  # the circle that takes the count past the budget
    assert refused.value.value == {"line": first_over + 1, "max_chords": budget, "chords": 158 * first_over}
    # the most such circles a program may hold: 158 n <= 10,000 + k (len(head) + n len(circle))
    k = ARC_CHORDS_PER_BYTE
    n = (10_000 + k * len(head)) // (158 - k * len(circle))
    assert read_program(head + circle * n).count == 1 + 158 * n     # every chord of them
    with pytest.raises(ArcBudgetError):
        read_program(head + circle * (n + 1))
    # a refusal under a small budget already beyond the size's budget is final
    with pytest.raises(ArcBudgetError) as small:
        read_program(text, ReadOptions(max_arc_chords=200))
    assert beyond_size_budget(small.value, len(text)) is None      # 316 chords counted: not yet beyond
    assert beyond_size_budget(refused.value, len(text)) is not None
    assert arc_chord_budget(10**9) == MAX_ARC_CHORDS


def test_no_reader_is_without_a_budget():
    from app.gcode.reader import BASE_ARC_CHORDS, ModalReader

    assert ModalReader(ReadOptions()).max_arc_chords == BASE_ARC_CHORDS == arc_chord_budget(0)
    assert ModalReader(ReadOptions(), size_bytes=1_000).max_arc_chords == BASE_ARC_CHORDS + ARC_CHORDS_PER_BYTE * 1_000
    assert ModalReader(ReadOptions(max_arc_chords=7)).max_arc_chords == 7
