"""plan_view_points: a trace polyline's top view made fit for cubic interpolation."""

from __future__ import annotations

import numpy as np
import pytest

from app.five_axis.errors import DegenerateTraceError
from app.five_axis.trace import MIN_TRACE_POINTS, plan_view_points


def test_long_polyline_passes_through_unchanged() -> None:
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [3.0, 1.0], [4.0, 3.0]])
    np.testing.assert_array_equal(plan_view_points(xy), xy)


def test_repeated_points_are_dropped() -> None:
    # a draped polyline's vertical steps project onto one plan-view point
    xy = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [1.0, 1e-5], [2.0, 0.0], [3.0, 0.0], [3.0, 0.0]])
    out = plan_view_points(xy, dedup_mm=1e-3)
    np.testing.assert_array_equal(out, [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])


def test_creeping_points_are_measured_from_the_last_kept_point() -> None:
    # ten steps of 0.6 * dedup: each is a duplicate of its neighbour but not of the kept point
    xy = np.column_stack([np.arange(11) * 0.6e-3, np.zeros(11)])
    out = plan_view_points(xy, min_points=2, dedup_mm=1e-3)
    np.testing.assert_allclose(out[:, 0], [0.0, 1.2e-3, 2.4e-3, 3.6e-3, 4.8e-3, 6.0e-3])


def test_two_point_segment_is_subdivided_at_midpoints() -> None:
    out = plan_view_points(np.array([[0.0, 0.0], [8.0, 0.0]]))
    assert out.shape == (MIN_TRACE_POINTS, 2)
    # first the midpoint 4, then the longer (first on ties) half [0, 4] gets 2
    np.testing.assert_allclose(out, [[0.0, 0.0], [2.0, 0.0], [4.0, 0.0], [8.0, 0.0]])


def test_the_longest_segment_is_split_first() -> None:
    out = plan_view_points(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 10.0]]))
    np.testing.assert_allclose(out, [[0.0, 0.0], [1.0, 0.0], [1.0, 5.0], [1.0, 10.0]])


def test_subdivision_reaches_the_requested_count_on_the_same_line() -> None:
    a, b = np.array([1.0, 2.0]), np.array([4.0, 6.0])
    out = plan_view_points(np.array([a, b]), min_points=9)
    assert out.shape == (9, 2)
    np.testing.assert_allclose(out, a + np.linspace(0.0, 1.0, 9)[:, None] * (b - a))  # 8 equal segments


@pytest.mark.parametrize("xy", [
    np.zeros((0, 2)),
    np.array([[1.0, 1.0]]),
    np.array([[1.0, 1.0], [1.0, 1.0 + 1e-7], [1.0, 1.0]]),
    np.array([[0.0, 0.0], [np.nan, 1.0]]),
    np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
    np.array([0.0, 1.0]),
])
def test_degenerate_input_is_a_typed_error_naming_the_trace(xy: np.ndarray) -> None:
    with pytest.raises(DegenerateTraceError) as info:
        plan_view_points(xy)
    assert info.value.field == "trace.xy"
