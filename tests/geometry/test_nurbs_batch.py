"""Many curves evaluated together equal each curve's own scipy evaluation, and a board's CL
points (all curves at once) equal the one-curve-at-a-time scipy reference."""

from __future__ import annotations

import numpy as np

from app.geometry.cl_points import cl_points, cl_points_many
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_batch import CurveBatch, row_search
from app.geometry.shapes import trace_curve
from app.geometry.tolerance import Tolerance
from app.reference.boards import board_traces, dome_part
from tests.helpers.cl_points_reference import reference_cl_points


def _curves(rng: np.random.Generator) -> list[NurbsCurve]:
    """A board's arcs and cubic curves, and random rational curves of degree 2-4 with
    uneven and doubled interior knots on a domain other than [0, 1]."""
    curves = [trace_curve(g) for g in board_traces(dome_part(), 60)]
    for i in range(30):
        p = int(rng.integers(2, 5))
        n = p + 1 + int(rng.integers(1, 7))
        inner = np.sort(rng.uniform(0, 1, n - p - 1))
        if i % 3 == 0 and inner.size >= 2:
            inner[1] = inner[0]
        knots = 1.0 + 3.0 * np.concatenate([np.zeros(p + 1), inner, np.ones(p + 1)])
        curves.append(NurbsCurve(p, knots, rng.uniform(-10, 10, (n, 2)), rng.uniform(0.5, 2.0, n)))
    return curves


def test_row_search_counts_like_searchsorted() -> None:
    rng = np.random.default_rng(1)
    rows = [np.sort(rng.integers(0, 9, int(rng.integers(0, 12))).astype(float)) for _ in range(50)]
    values = np.concatenate(rows)
    start = np.concatenate([[0], np.cumsum([r.size for r in rows])[:-1]])
    which = rng.integers(0, 50, 500)
    x = rng.integers(-1, 10, 500).astype(float)
    found = row_search(values, start[which], np.array([rows[i].size for i in which]), x)
    assert np.array_equal(found, [np.searchsorted(rows[i], v, side="right") for i, v in zip(which, x)])


def test_a_batch_evaluates_every_curve_as_scipy_does() -> None:
    rng = np.random.default_rng(2)
    curves = _curves(rng)
    queries = [np.concatenate([np.linspace(*c.domain, 25), np.unique(c.knots), rng.uniform(*c.domain, 10)])
               for c in curves]
    which = np.repeat(np.arange(len(curves)), [q.size for q in queries])
    u = np.concatenate(queries)
    batch = CurveBatch(curves)
    d = batch.derivatives(which, u, 2)
    for i, curve in enumerate(curves):
        ref = curve.derivatives(queries[i], 2)
        scale = np.abs(ref).max(axis=(0, 1)) + 1.0
        assert (np.abs(d[:, which == i] - ref) <= 1e-12 * scale).all()
        np.testing.assert_allclose(batch.curvature(d[:, which == i]), curve.curvature(queries[i], ref),
                                   rtol=1e-10, atol=1e-12)
        alone = CurveBatch([curve]).derivatives(np.zeros(queries[i].size, dtype=np.int64), queries[i], 2)
        assert np.array_equal(alone, d[:, which == i])  # the same bits alone as in the batch


def test_a_boards_cl_points_equal_the_scipy_reference_one_curve_at_a_time() -> None:
    chord = Tolerance().chord_mm
    curves = [trace_curve(g) for g in board_traces(dome_part(), 300, seed=3)]
    batched = cl_points_many(curves, chord)
    for curve, many in zip(curves, batched):
        ref = reference_cl_points(curve, chord)
        assert many.u.shape == ref.u.shape
        np.testing.assert_allclose(many.u, ref.u, rtol=0, atol=1e-12)
        np.testing.assert_allclose(many.points, ref.points, rtol=0, atol=1e-9)
        assert abs(many.max_sagitta_mm - ref.max_sagitta_mm) <= 1e-9
        assert many.max_sagitta_mm <= chord
    alone = [cl_points(c, chord) for c in curves[::7]]
    for one, many in zip(alone, batched[::7]):
        assert np.array_equal(one.points, many.points) and one.max_sagitta_mm == many.max_sagitta_mm
