"""Preprocessing: smoothing formulas against independent references, bad points, holes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.reconstruction.surface_fit.errors import SurfaceFitError
from app.reconstruction.surface_fit.grid import HeightGrid
from app.reconstruction.surface_fit.preprocess import (
    densify_grid,
    fill_holes,
    find_bad_points,
    five_point_cubic,
    interpolate_heights,
    moving_average,
    spline_smooth,
)

coef = st.floats(-3, 3, allow_nan=False)


@given(coef, coef, coef, coef, st.integers(5, 30))
@settings(max_examples=30, deadline=None)
def test_five_point_cubic_reproduces_cubics(a, b, c, d, n) -> None:
    t = np.linspace(-1, 2, n)
    y = a + b * t + c * t**2 + d * t**3
    np.testing.assert_allclose(five_point_cubic(y), y, atol=1e-10)


def test_five_point_cubic_equals_a_least_squares_cubic_per_window() -> None:
    rng = np.random.default_rng(3)
    y = rng.normal(size=12)
    t = np.arange(12.0)
    out = five_point_cubic(y)
    for i in range(12):
        lo = min(max(i - 2, 0), 12 - 5)
        p = np.polyfit(t[lo:lo + 5], y[lo:lo + 5], 3)
        assert out[i] == pytest.approx(np.polyval(p, t[i]), abs=1e-12)


def test_moving_average_matches_convolution_and_keeps_lines() -> None:
    rng = np.random.default_rng(4)
    y = rng.normal(size=(15, 3))
    out = moving_average(y, 5, axis=0)
    ref = np.convolve(y[:, 1], np.ones(5) / 5, mode="valid")
    np.testing.assert_allclose(out[2:-2, 1], ref, atol=1e-14)
    line = 2.0 + 0.5 * np.arange(9.0)
    np.testing.assert_allclose(moving_average(line, 5), line, atol=1e-12)
    with pytest.raises(SurfaceFitError):
        moving_average(line, 4)


def test_spline_smoothing_keeps_lines_and_reduces_noise() -> None:
    x = np.linspace(0, 10, 40)
    np.testing.assert_allclose(spline_smooth(x, 1.0 + 0.3 * x), 1.0 + 0.3 * x, atol=1e-8)
    rng = np.random.default_rng(5)
    truth = np.sin(x / 3)
    noisy = truth + rng.normal(0, 0.05, x.size)
    assert np.abs(spline_smooth(x, noisy) - truth).std() < np.abs(noisy - truth).std()


def _sphere_points(n: int = 20, noise: float = 0.005, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.linspace(-20, 20, n)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    zz = np.sqrt(50.0**2 - xx**2 - yy**2) + rng.normal(0, noise, xx.shape)
    return np.column_stack([xx.ravel(), yy.ravel(), zz.ravel()])


def test_bad_points_found_exactly() -> None:
    pts = _sphere_points()
    spikes = {17: 0.3, 205: -0.2, 250: 0.05}  # edge, interior, small interior
    for i, dz in spikes.items():
        pts[i, 2] += dz
    result = find_bad_points(pts)
    assert sorted(np.flatnonzero(result.bad).tolist()) == sorted(spikes)
    assert 0.01 <= result.threshold_mm < 0.04


def test_fill_holes_and_densify_reproduce_a_smooth_surface() -> None:
    x = np.linspace(-20, 20, 15)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    z = np.sqrt(50.0**2 - xx**2 - yy**2)
    holed = z.copy()
    holed[3, 4] = holed[7, 7] = holed[0, 14] = np.nan
    filled = fill_holes(HeightGrid(x, x, holed))
    assert not np.isnan(filled.z).any()
    err = np.abs(filled.z - z)
    assert err[3, 4] < 1e-3 and err[7, 7] < 1e-3
    assert err[0, 14] < 0.02  # extrapolated corner of a steep cap
    dense = densify_grid(HeightGrid(x, x, z), 3)
    assert dense.z.shape == (43, 43)
    dx, dy = np.meshgrid(dense.x, dense.y, indexing="ij")
    assert np.abs(dense.z - np.sqrt(50.0**2 - dx**2 - dy**2)).max() < 2e-3


def test_preprocessing_steps_raise_typed_errors_on_degenerate_points() -> None:
    t = np.arange(40.0)
    line = np.column_stack([t, -t, np.zeros(40)])
    with pytest.raises(SurfaceFitError) as info:
        find_bad_points(line, field="points")
    assert info.value.field == "points" and "one line" in info.value.message
    with pytest.raises(SurfaceFitError) as info:
        find_bad_points(np.tile([[1.0, 2.0, 3.0]], (40, 1)))
    assert info.value.field == "points" and info.value.value["distinct"] == 1
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 10, (30, 2))
    twice = np.vstack([np.column_stack([xy, np.zeros(30)])] * 2)
    with pytest.raises(SurfaceFitError) as info:
        interpolate_heights(twice, xy[:3], field="points")
    assert info.value.field == "points" and info.value.value == {"repeats": 30}


def test_thin_plate_resampling_of_a_ring_reproduces_a_plane() -> None:
    """Points on a circle determine no cubic term (x^2 + y^2 - r^2 vanishes on them);
    the linear thin-plate spline is used and reproduces a plane exactly."""
    phi = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    x, y = 5 * np.cos(phi), 5 * np.sin(phi)
    ring = np.column_stack([x, y, 0.3 * x - 0.2 * y + 1.0])
    query = np.array([[0.0, 0.0], [1.0, -2.0], [3.0, 2.5]])
    np.testing.assert_allclose(interpolate_heights(ring, query),
                               0.3 * query[:, 0] - 0.2 * query[:, 1] + 1.0, atol=1e-8)
