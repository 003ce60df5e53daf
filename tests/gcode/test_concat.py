"""Joining single-trace programs into one whole-part program: every trace's dispensed path
kept exactly, travel between traces only at the safe height, nearest-neighbour order, the
dialect's header once and its end once; programs that cannot be spliced are refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.gcode.concat import join_programs
from app.gcode.reader import ReadOptions, read_program
from app.gcode.writer import GcodeError, ProgramBuilder

OPTIONS = ReadOptions(dispense_on="M106", dispense_off="M107")


def trace_program(dialect: str, start: tuple[float, float], length: float, top_z: float) -> str:
    """A compensate-like program: lift, go to the start, plunge, dispense along +x on a bump."""
    b = ProgramBuilder(dialect, "compensate", "job_x")
    b.comment("one trace")
    x0, y0 = start
    xs = np.linspace(x0, x0 + length, 12)
    zs = 1.0 + 0.2 * np.sin(xs)
    b.rapid(z=top_z).rapid(x=x0, y=y0).rapid(z=zs[0] + 0.5).move(z=zs[0], feed_mm_min=100)
    b.raw("M106")
    for i, (x, z) in enumerate(zip(xs[1:], zs[1:])):
        b.move(x=float(x), y=y0, z=float(z), feed_mm_min=600 if i == 0 else None)
    b.raw("M107")
    b.rapid(z=top_z)
    b.end()
    return b.text()


def dispensed(text: str) -> np.ndarray:
    program = read_program(text, OPTIONS)
    return np.hstack([program.start[program.dispense, :3], program.end[program.dispense, :3]])


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_joined_program_keeps_every_path_and_travels_only_at_the_safe_height(dialect):
    starts = [(50.0, 0.0), (0.0, 10.0), (5.0, 30.0)]
    tops = [3.0, 4.5, 3.5]
    programs = [(f"t{i}", trace_program(dialect, s, 8.0, top)) for i, (s, top) in enumerate(zip(starts, tops))]
    joined = join_programs(programs, dialect, clearance_mm=2.0, job_id="loop_1")
    # nearest neighbour from the origin: (0, 10) first, then (5, 30), then (50, 0)
    assert joined.order == (1, 2, 0)
    assert joined.safe_z_mm == pytest.approx(4.5 + 2.0)
    expected_travel = np.hypot(0, 10) + np.hypot(5, 20) + np.hypot(45, 30)
    assert joined.travel_xy_mm == pytest.approx(expected_travel)
    # the dispensed path is each program's, in the joined order, to the written decimals
    assert np.allclose(dispensed(joined.text), np.vstack([dispensed(programs[i][1]) for i in joined.order]), atol=1e-4)
    # every sideways move that is not dispensing, outside the traces' own bodies, is at the safe height
    program = read_program(joined.text, OPTIONS)
    lateral = np.linalg.norm(program.end[:, :2] - program.start[:, :2], axis=1) > 1e-9
    travel = lateral & ~program.dispense
    assert travel.any()
    assert np.all(program.start[travel, 2] >= min(tops) - 1e-9)  # never below a program's own travel height
    between = travel & (np.linalg.norm(program.start[:, :2] - program.end[:, :2], axis=1) > 1.0)
    assert np.all(program.start[between, 2] == pytest.approx(joined.safe_z_mm))
    lines = joined.text.splitlines()
    assert lines.count("G21") == 1 and lines.count("G90") == 1
    assert lines.count("M2") == (1 if dialect == "grbl" else 0)
    assert dialect != "grbl" or lines[-1] == "M2"


def test_programs_that_cannot_be_spliced_are_refused():
    good = trace_program("marlin", (0, 0), 5, 3)
    with pytest.raises(GcodeError) as wrong_dialect:
        join_programs([("a", trace_program("grbl", (0, 0), 5, 3)), ("b", good)], "marlin")
    assert wrong_dialect.value.field == "dialect"
    relative = good.replace("M106", "G91\nM106")
    with pytest.raises(GcodeError, match="G91"):
        join_programs([("rel", relative)], "marlin")
    with pytest.raises(GcodeError):
        join_programs([], "marlin")
    with pytest.raises(GcodeError):
        join_programs([("a", good)], "marlin", clearance_mm=0)


def test_the_order_is_the_greedy_nearest_neighbour_from_the_origin_lowest_index_on_a_tie():
    from app.gcode.concat import _nearest_first

    rng = np.random.default_rng(5)
    starts = np.concatenate([rng.uniform(-50, 150, (300, 2)), [[3.0, 4.0], [4.0, 3.0], [3.0, 4.0]]])
    left, here, want, travel = list(range(len(starts))), np.zeros(2), [], 0.0
    while left:                                   # the plain scan of every start left, each step
        nearest = min(left, key=lambda i: math.dist(starts[i], here))
        travel += math.dist(starts[nearest], here)
        here = starts[nearest]
        want.append(nearest)
        left.remove(nearest)
    order, got = _nearest_first(starts)
    assert order == want and got == pytest.approx(travel, rel=1e-12)
    assert _nearest_first(np.array([[3.0, 4.0], [4.0, 3.0]]))[0] == [0, 1]   # 5 mm both: the first
