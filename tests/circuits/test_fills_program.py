"""Fills cover their outline, wide traces get side-by-side passes, the circuit program
orders strokes for short travel and prints each between the dispense codes."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Polygon

from app.circuits.fills import fill_strokes, offset_polyline, pass_offsets
from app.circuits.layout import circle_ring
from app.circuits.program import Stroke, order_strokes, write_circuit_program
from app.circuits.strokes import deviation_field, trace_passes, trace_passes_many


@pytest.mark.parametrize("outline", [
    np.array([[0, 0], [2, 0], [2, 1], [0, 1]], float),
    circle_ring(np.zeros(2), 0.6, 0.001),
    np.array([[0, 0], [3, 0], [3, 0.5], [0.5, 0.5], [0.5, 2], [0, 2]], float),   # an L
])
def test_fill_beads_cover_the_outline_and_stay_inside_it(outline):
    w = 0.2
    strokes = fill_strokes(outline, [], w)
    beads = shapely.union_all([LineString(s).buffer(w / 2) for s in strokes])
    pad = Polygon(outline)
    assert beads.intersection(pad).area >= 0.98 * pad.area
    assert beads.difference(pad.buffer(1e-6)).area <= 0.02 * pad.area + 1e-9


def test_passes_are_centred_and_span_the_width():
    np.testing.assert_allclose(pass_offsets(0.2, 0.2), [0.0])
    offsets = pass_offsets(0.5, 0.2)
    assert len(offsets) == 3 and offsets.sum() == pytest.approx(0.0)
    assert offsets.max() + 0.1 == pytest.approx(0.25)          # outer bead edge at the trace edge
    xy = np.array([[0, 0], [1, 0], [1, 1]], float)
    moved = offset_polyline(xy, 0.1)
    assert LineString(moved).hausdorff_distance(LineString(xy).offset_curve(0.1, join_style="mitre")) < 1e-9


def test_side_passes_follow_the_nominal_slope():
    tip = np.column_stack([np.linspace(0, 10, 11), np.zeros(11), np.full(11, 1.0)])
    passes = trace_passes(tip, 0.5, 0.2, lambda xy: 0.1 * xy[:, 1])        # the surface rises with y
    assert len(passes) == 3
    for p in passes:
        np.testing.assert_allclose(p[:, 2], 1.0 + 0.1 * p[:, 1], atol=1e-12)


def test_deviation_field_interpolates_linearly_and_holds_outside():
    xy = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], float)
    field = deviation_field(xy, 0.01 * xy[:, 0])
    np.testing.assert_allclose(field(np.array([[5.0, 5.0], [2.5, 7.5]])), [0.05, 0.025], atol=1e-12)
    assert field(np.array([[20.0, 0.0]]))[0] == pytest.approx(0.1)


def _greedy_by_scan(strokes: list[Stroke]) -> list[tuple[int, bool]]:
    """The greedy nearest-end order by scanning every open end at each step (the reference)."""
    heads = np.array([s.points[0, :2] for s in strokes])
    tails = np.array([s.points[-1, :2] for s in strokes])
    left, at, order = np.ones(len(strokes), bool), np.zeros(2), []
    for _ in strokes:
        dh = np.where(left, np.linalg.norm(heads - at, axis=1), np.inf)
        dt = np.where(left, np.linalg.norm(tails - at, axis=1), np.inf)
        i_h, i_t = int(np.argmin(dh)), int(np.argmin(dt))
        i, rev = (i_h, False) if dh[i_h] <= dt[i_t] else (i_t, True)
        order.append((i, rev))
        left[i] = False
        at = heads[i] if rev else tails[i]
    return order


@pytest.mark.parametrize("n", [1, 2, 37, 1500])
def test_the_tree_search_orders_as_the_scan_of_every_end(n):
    """Random strokes (no ties), clustered rows (the tree is rebuilt many times and the nearest
    ends are printed ones): the same order, stroke for stroke, as the O(n^2) scan."""
    rng = np.random.default_rng(n)
    start = rng.uniform(0, 150, (n, 2))
    step = rng.normal(0, 2, (n, 2))
    random = [Stroke(np.column_stack([np.vstack([a, a + d]), [1.0, 1.0]]), "trace", "t", 300.0)
              for a, d in zip(start, step)]
    assert order_strokes(random) == _greedy_by_scan(random)
    rows = [Stroke(np.array([[3.0 * k + 0.01 * r, 1.15 * r + 1e-4 * k, 1.0], [3.0 * k + 3.0, 1.15 * r, 1.0]]),
                   "trace", "t", 300.0) for r in range(max(1, n // 50)) for k in range(min(n, 50))]
    assert order_strokes(rows) == _greedy_by_scan(rows)


def test_program_orders_strokes_for_short_travel():
    rng = np.random.default_rng(4)
    strokes = []
    for k in rng.permutation(20):
        a = np.array([k * 2.0, 0.0, 1.0])
        strokes.append(Stroke(np.vstack([a, a + [0, 5, 0]]), "trace", f"t{k}", 300.0))
    program = write_circuit_program(strokes, dialect="marlin", dispense_on="M106", dispense_off="M107",
                                    clearance_mm=2.0, part_top_mm=1.0)
    assert program.travel_mm < 0.5 * program.travel_input_order_mm
    lines = program.text.splitlines()
    assert lines.count("M106") == 20 and lines.count("M107") == 20
    assert sorted(i for i, _ in program.order) == list(range(20))


def test_many_traces_passes_are_each_traces_own_from_one_surface_evaluation():
    """Narrow and wide traces together: the same passes as one trace at a time, with the surface
    (z = 0.1 x + 0.05 y^2) evaluated once for all of them."""
    calls: list[int] = []

    def surface_z(xy: np.ndarray) -> np.ndarray:
        calls.append(len(xy))
        return 0.1 * xy[:, 0] + 0.05 * xy[:, 1] ** 2

    rng = np.random.default_rng(2)
    tips = [np.column_stack([np.linspace(0, 5, 7) + i, np.sin(np.linspace(0, 2, 7)) + i, rng.uniform(1, 2, 7)])
            for i in range(6)]
    widths = [0.1, 0.5, 0.2, 0.9, 0.15, 0.45]
    many = trace_passes_many(tips, widths, 0.2, surface_z)
    assert len(calls) == 1
    for tip, width, passes in zip(tips, widths, many):
        alone = trace_passes(tip, width, 0.2, surface_z)
        assert len(passes) == len(alone) == max(1, int(np.ceil(width / 0.2 - 1e-9)))
        for a, b in zip(passes, alone):
            np.testing.assert_allclose(a, b, atol=1e-12)
