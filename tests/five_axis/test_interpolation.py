"""Constant-feed Taylor interpolation, checked on an exact NURBS circle arc."""

from __future__ import annotations

import numpy as np
import pytest

from app.five_axis.errors import DegenerateTraceError
from app.five_axis.interpolation import (
    feed_fluctuation,
    interpolate_parameters,
    segment_arc_lengths,
)
from app.geometry.nurbs import NurbsCurve

R = 20.0


def _quarter_circle() -> NurbsCurve:
    """Exact rational quadratic quarter circle of radius R in the z = 5 plane (its speed
    |p'(u)| varies along u, so u is far from arc length)."""
    pts = np.array([[R, 0, 5.0], [R, R, 5.0], [0, R, 5.0]])
    return NurbsCurve(2, np.array([0, 0, 0, 1, 1, 1.0]), pts, np.array([1, np.sqrt(0.5), 1]))


def _true_steps(curve: NurbsCurve, u: np.ndarray) -> np.ndarray:
    """Arc length of each step from the circle's angle (independent of any quadrature)."""
    p = curve.evaluate(u)
    ang = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    return R * np.diff(ang)


@pytest.mark.parametrize("order", [1, 2])
def test_schedule_covers_the_arc_at_constant_feed(order: int) -> None:
    curve = _quarter_circle()
    sched = interpolate_parameters(curve, feed_mm_s=10.0, period_s=0.005, order=order)
    ds = 0.05
    steps = _true_steps(curve, sched.u)
    assert sched.u[0] == 0.0 and sched.u[-1] == 1.0
    assert steps[:-1].size == int(np.floor(np.pi / 2 * R / ds - 1e-9))
    rel = np.abs(steps[:-1] - ds) / ds
    fl = feed_fluctuation(curve, sched)
    assert fl.max_rel == pytest.approx(rel.max(), rel=1e-6, abs=1e-12)
    np.testing.assert_allclose(segment_arc_lengths(curve, sched.u), steps, rtol=1e-10)


def test_second_order_error_is_third_order_in_the_step() -> None:
    """Per-step error: first order ~ ds^2, second order ~ ds^3 (relative: ds and ds^2)."""
    curve = _quarter_circle()
    errs = {1: [], 2: []}
    for ds in (0.2, 0.1):
        for order in (1, 2):
            sched = interpolate_parameters(curve, feed_mm_s=ds, period_s=1.0, order=order)
            errs[order].append(feed_fluctuation(curve, sched).max_rel)
    assert errs[2][0] < 1e-3 and errs[2][0] < errs[1][0] / 10
    assert errs[1][0] / errs[1][1] == pytest.approx(2.0, rel=0.15)
    assert errs[2][0] / errs[2][1] == pytest.approx(4.0, rel=0.2)


def test_bad_feed_is_typed() -> None:
    with pytest.raises(DegenerateTraceError) as info:
        interpolate_parameters(_quarter_circle(), feed_mm_s=0.0, period_s=0.001)
    assert info.value.field == "params"
