"""merge_plans: per-trace plans joined into one program's stations; FieldPlan's views."""

from __future__ import annotations

import numpy as np
import pytest

from app.probing.field import FieldPlan
from app.probing.merge import merge_plans
from app.probing.selection import PlanError, ProbePlan


def _plan(s: list[float], z: float, normals: bool = True) -> ProbePlan:
    s_mm = np.array(s)
    points = np.column_stack([s_mm, np.full(len(s), z), np.zeros(len(s))])
    n = np.tile([0.0, 0.0, 1.0], (len(s), 1)) if normals else None
    return ProbePlan("chord", s_mm, points, n)


def test_stations_are_joined_in_trace_order_with_each_trace_first_index() -> None:
    plans = [_plan([0.0, 1.0, 2.0], 0.0), _plan([0.5], 4.0), _plan([0.0, 3.0], 8.0)]
    merged, first = merge_plans(plans, "chord")
    assert merged.method == "chord" and merged.count == 6
    np.testing.assert_array_equal(first, [0, 3, 4])
    for plan, f in zip(plans, first):
        np.testing.assert_array_equal(merged.points[f:f + plan.count], plan.points)
        np.testing.assert_array_equal(merged.s_mm[f:f + plan.count], plan.s_mm)  # arc length not re-based
    assert merged.normals is not None and merged.normals.shape == (6, 3)


def test_one_plan_without_normals_leaves_the_merged_plan_without() -> None:
    merged, _ = merge_plans([_plan([0.0, 1.0], 0.0), _plan([0.0, 1.0], 1.0, normals=False)], "minimax")
    assert merged.normals is None and merged.method == "minimax"


def test_no_plans_is_a_plan_error() -> None:
    with pytest.raises(PlanError) as info:
        merge_plans([], "chord")
    assert info.value.field == "trace_ids"


def test_field_plan_counts_stations_per_trace_and_marks_off_trace_arc_length() -> None:
    trace = np.array([0, -1, 2, 0, 2, 2])
    s_mm = np.array([0.0, np.nan, 1.0, 2.0, 3.0, 4.0])
    n = len(trace)
    plan = FieldPlan(xy=np.column_stack([np.arange(n, dtype=float), np.zeros(n)]), z=np.ones(n),
                     grad=np.zeros((n, 2)), trace=trace, s_mm=s_mm, center=np.zeros(2), max_sd_mm=0.01,
                     trace_sd_mm=np.full(4, 0.01), dof=3.0, area_mm2=1.0, stations_mode="on_traces",
                     order=np.arange(n))
    np.testing.assert_array_equal(plan.stations_per_trace, [2, 0, 3, 0])  # four traces, one off-trace station
    probe = plan.probe_plan()
    assert probe.method == "field" and probe.count == n
    np.testing.assert_array_equal(probe.s_mm, [0.0, -1.0, 1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(probe.points[:, 2], np.ones(n))
    assert probe.normals is not None
    np.testing.assert_allclose(probe.normals, np.tile([0.0, 0.0, 1.0], (n, 1)))
