"""Building many traces at once (CL points, draping) gives exactly what building each one gives."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.cl_points import cl_points, cl_points_many
from app.geometry.drape import DrapedPath, drape_polyline
from app.geometry.drape_batch import drape_polylines
from app.geometry.shapes import trace_curve
from app.geometry.tolerance import Tolerance
from app.geometry.traces import build_nominal_trace, build_nominal_traces
from app.reference.boards import board_traces, dome_part


@pytest.fixture(scope="module")
def dome():  # type: ignore[no-untyped-def]
    part = dome_part()
    return part, part.mesh(grid_mm=0.5)


def _random_polylines(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """Random top-view polylines inside the 150 x 100 mm dome: random walks of 2-40 points with
    steps from 1 um to 40 mm, some repeated points, some on the mesh's grid lines."""
    out = []
    for _ in range(count):
        n = int(rng.integers(2, 40))
        steps = rng.normal(size=(n, 2)) * 10.0 ** rng.uniform(-3, 1.6, size=(n, 1))
        xy = np.clip(rng.uniform([5, 5], [145, 95]) + np.cumsum(steps, axis=0), 1.0, [149.0, 99.0])
        if rng.random() < 0.3:
            xy[rng.integers(n)] = xy[rng.integers(n)]  # a repeated point
        if rng.random() < 0.3:
            xy = np.round(xy * 2.0) / 2.0  # on the grid lines
        if np.linalg.norm(np.diff(xy, axis=0), axis=1).sum() > 0.01:
            out.append(xy)
    return out


def _assert_identical(batch: list[DrapedPath], single: list[DrapedPath]) -> None:
    assert len(batch) == len(single)
    for b, s in zip(batch, single):
        np.testing.assert_array_equal(b.points, s.points)
        np.testing.assert_array_equal(b.normals, s.normals)
        np.testing.assert_array_equal(b.s_mm, s.s_mm)
        assert (b.xy_length_mm, b.length_mm, b.slope_stretch) == (s.xy_length_mm, s.length_mm, s.slope_stretch)


def test_random_polylines_drape_exactly_as_one_by_one(dome):  # type: ignore[no-untyped-def]
    _, mesh = dome
    xys = _random_polylines(np.random.default_rng(3), 300)
    batch = drape_polylines(mesh, xys)
    assert batch is not None
    _assert_identical(batch, [drape_polyline(mesh, xy) for xy in xys])
    assert sum(len(b.points) for b in batch) > 10 * sum(len(xy) for xy in xys)  # the crossings are in


def test_a_batch_with_a_trace_off_the_part_or_of_zero_length_is_left_to_the_caller(dome):  # type: ignore[no-untyped-def]
    _, mesh = dome
    good = [np.array([[10.0, 10.0], [40.0, 30.0]])]
    assert drape_polylines(mesh, good + [np.array([[140.0, 50.0], [160.0, 50.0]])]) is None
    assert drape_polylines(mesh, good + [np.array([[20.0, 20.0], [20.0, 20.0]])]) is None
    assert drape_polylines(mesh, []) == []


def test_a_board_builds_the_same_nominal_traces_batched(dome):  # type: ignore[no-untyped-def]
    part, mesh = dome
    geometries = board_traces(part, 60)
    batch = build_nominal_traces(mesh, geometries, Tolerance())
    assert batch is not None
    for b, geometry in zip(batch, geometries):
        s = build_nominal_trace(mesh, geometry, "xy", Tolerance())
        assert b.to_dict() == s.to_dict()
        np.testing.assert_array_equal(b.s, s.s)
    assert build_nominal_traces(mesh, [*geometries[:3], {"type": "line", "start": [0, 0, 0], "end": [1, 1, 1]}],
                                Tolerance()) is None
    too_long = {"type": "line", "start": [0, 0], "end": [20_000, 0]}  # over the length limit
    assert build_nominal_traces(mesh, [*geometries[:3], too_long], Tolerance()) is None


def test_cl_points_of_many_curves_are_each_curves_own(dome):  # type: ignore[no-untyped-def]
    part, _ = dome
    curves = [trace_curve(g, tolerance=Tolerance()) for g in board_traces(part, 200, seed=5)]
    assert {(c.degree, c.is_rational) for c in curves} == {(1, False), (2, True), (3, False)}
    for many, one in zip(cl_points_many(curves, 0.01), (cl_points(c, 0.01) for c in curves)):
        np.testing.assert_array_equal(many.u, one.u)
        np.testing.assert_array_equal(many.points, one.points)
        assert many.max_sagitta_mm == one.max_sagitta_mm <= 0.01
