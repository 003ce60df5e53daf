"""Scan cost model, scan path timing and scan plans: analytic answers and the planner's choices."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.geometry.traces import as_trace_polyline
from app.probing.scan_cost import MotionCost, move_time, pass_time, touch_time
from app.probing.scan_path import ScanPathError, positions_at, sample_positions
from app.probing.scan_plan import ScanPlanError, plan_scans


def test_move_time_is_the_trapezoid_or_the_triangle():
    assert move_time(100.0, 100.0, 1000.0) == pytest.approx(1.0 + 0.1)     # reaches 100 mm/s
    assert move_time(2.5, 100.0, 1000.0) == pytest.approx(2 * math.sqrt(2.5 / 1000))  # never does
    assert move_time(10.0, 100.0, 1000.0) == pytest.approx(0.2)            # exactly v^2 / a: both agree


def test_a_touch_costs_hops_approach_trigger_and_retract():
    cost = MotionCost()
    one = touch_time(cost, np.array([[0.0, 0.0]]))
    assert one == pytest.approx(1.0 / (100 / 60) + 0.02 + 2 * math.sqrt(1.0 / 1000))  # approach, trigger, retract
    two = touch_time(cost, np.array([[0.0, 0.0], [30.0, 0.0]]))
    assert two - one == pytest.approx(one + 2 * 2 * math.sqrt(2 / 1000) + float(move_time(30.0, 100, 1000)))


def test_positions_follow_the_pass_at_constant_speed_and_the_time_offset_shifts_them_back():
    w = np.array([[0.0, 0.0, 1.0], [10.0, 0.0, 1.0], [10.0, 5.0, 1.0]])
    p = positions_at(w, 10.0, np.array([-1.0, 0.5, 1.25, 9.0]))
    assert np.allclose(p, [[0, 0, 1], [5, 0, 1], [10, 2.5, 1], [10, 5, 1]])
    shifted = sample_positions(w, 10.0, 3, 100.0, time_offset_s=0.01)  # stamps 0, 0.01, 0.02 s
    assert np.allclose(shifted[:, 0], [0.0, 0.0, 0.1])
    with pytest.raises(ScanPathError):
        positions_at(w[:1], 10.0, np.array([0.0]))


def _lines(count: int, length: float, width: float) -> list:
    """``count`` straight traces of ``length`` across a ``width`` wide flat part."""
    ys = np.linspace(5.0, width - 5.0, count)
    return [as_trace_polyline(np.array([[5.0, y, 0.0], [5.0 + length, y, 0.0]])) for y in ys]


def test_the_planner_rasters_dense_tiles_and_scans_sparse_ones():
    flat = lambda xy: np.zeros(len(xy))  # noqa: E731
    cost = MotionCost()
    dense = _lines(40, 50.0, 60.0)            # 40 traces 1.3 mm apart: one raster line per 5 mm is cheaper
    plan = plan_scans(dense, flat, (0.0, 0.0, 60.0, 60.0), cost, spacing_mm=5.0)
    assert plan.tiles["raster"] >= 1 and plan.tiles["trace"] == 0
    traced = plan_scans(dense, flat, (0.0, 0.0, 60.0, 60.0), cost, spacing_mm=5.0, mode="traces")
    assert traced.machine_s > plan.machine_s and len(traced.passes) == 40
    sparse = _lines(2, 20.0, 60.0)            # two short traces: scanning them beats rastering the tiles
    plan = plan_scans(sparse, flat, (0.0, 0.0, 60.0, 60.0), cost, spacing_mm=5.0)
    assert plan.tiles["trace"] >= 1 and {p.kind for p in plan.passes} == {"trace"}
    assert plan.scan_s == pytest.approx(sum(pass_time(cost, 20.0) for _ in range(2)))
    with pytest.raises(ScanPlanError):
        plan_scans(sparse, flat, (0.0, 0.0, 60.0, 60.0), cost, spacing_mm=0.0)


def test_raster_lines_cover_the_bounds_from_rim_to_rim():
    flat = lambda xy: np.zeros(len(xy))  # noqa: E731
    plan = plan_scans(_lines(40, 50.0, 60.0), flat, (0.0, 2.0, 60.0, 58.0), MotionCost(), 7.0, mode="raster")
    ys = sorted({float(p.spot[0, 1]) for p in plan.passes})
    assert ys[0] == pytest.approx(2.0) and ys[-1] == pytest.approx(58.0) and np.diff(ys).max() <= 7.0 + 1e-9


@pytest.mark.parametrize("spacing", [5.0, 6.0, 6.5, 7.0])
def test_raster_rows_run_on_from_where_the_row_before_ended(spacing):
    """Whatever the number of lines per row of tiles, the raster is one serpentine: each line
    starts where the line before ended plus one spacing in y (no move back across the part,
    one hop: the first line's).  The traces are straight lines given by their two ends: the
    tiles between the ends are crossed, so rastered too."""
    flat = lambda xy: np.zeros(len(xy))  # noqa: E731
    cost = MotionCost()
    plan = plan_scans(_lines(60, 140.0, 100.0), flat, (0.0, 0.0, 150.0, 100.0), cost, spacing, mode="raster")
    links = [float(np.linalg.norm(b.spot[0, :2] - a.spot[-1, :2])) for a, b in zip(plan.passes, plan.passes[1:])]
    assert max(links) <= spacing + 1e-9 and [p.hop for p in plan.passes].count(True) == 1
    assert plan.link_s == pytest.approx(sum(float(move_time(d, cost.travel_mm_s, cost.accel_mm_s2)) for d in links))


def test_touches_are_ordered_into_a_short_tour():
    from app.probing.scan_cost import touch_order

    xy = np.array([[0.0, 0.0], [100.0, 0.0], [10.0, 0.0], [90.0, 0.0], [50.0, 0.0]])
    order = touch_order(xy, np.array([-5.0, 0.0]))
    assert order.tolist() == [0, 2, 4, 3, 1]
    assert touch_time(MotionCost(), xy[order]) < touch_time(MotionCost(), xy)
    assert touch_order(np.zeros((0, 2))).tolist() == []
