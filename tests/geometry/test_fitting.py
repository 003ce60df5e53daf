"""Fitting: interpolation through every point, equality with geomdl, noise-aware fits."""

from __future__ import annotations

import numpy as np
import pytest
from geomdl import fitting as gfit

from app.geometry.errors import DegenerateGeometryError, GeometryError
from app.geometry.fitting import (
    approximate_curve,
    curve_parameters,
    fit_surface,
    interpolate_curve,
    interpolate_surface,
    smooth_curve,
)


def wiggle(n: int, seed: int = 0, dim: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, n) + rng.uniform(0, 0.8 * 2 * np.pi / n, n)  # uneven, increasing
    pts = np.column_stack([10 * np.cos(t), 8 * np.sin(t), 2 * t])
    return pts[:, :dim]


@pytest.mark.parametrize("n,degree,dim", [(6, 3, 3), (25, 3, 2), (30, 2, 3), (12, 5, 3), (9, 1, 2)])
def test_interpolation_matches_geomdl(n: int, degree: int, dim: int) -> None:
    pts = wiggle(n, seed=n, dim=dim)
    curve = interpolate_curve(pts, degree)
    ref = gfit.interpolate_curve(pts.tolist(), degree)
    assert np.abs(np.array(ref.ctrlpts) - curve.control_points).max() < 1e-9
    assert np.abs(np.array(ref.knotvector) - curve.knots).max() < 1e-12
    assert np.abs(curve.evaluate(curve_parameters(pts)) - pts).max() < 1e-9


def test_centripetal_matches_geomdl_and_passes_points() -> None:
    pts = wiggle(20, seed=7)
    curve = interpolate_curve(pts, 3, "centripetal")
    ref = gfit.interpolate_curve(pts.tolist(), 3, centripetal=True)
    assert np.abs(np.array(ref.ctrlpts) - curve.control_points).max() < 1e-9
    assert np.abs(curve.evaluate(curve_parameters(pts, "centripetal")) - pts).max() < 1e-9


def test_interpolation_passes_every_point_at_scale() -> None:
    pts = wiggle(2000, seed=1)
    curve = interpolate_curve(pts)
    assert np.abs(curve.evaluate(curve_parameters(pts)) - pts).max() < 1e-9


def test_least_squares_matches_geomdl_and_keeps_ends() -> None:
    pts = wiggle(40, seed=3)
    curve = approximate_curve(pts, 9)
    ref = gfit.approximate_curve(pts.tolist(), 3, ctrlpts_size=9)
    assert np.abs(np.array(ref.ctrlpts) - curve.control_points).max() < 1e-9
    assert np.allclose(curve.evaluate([0, 1]), pts[[0, -1]], atol=1e-12)


def test_least_squares_reproduces_a_cubic_exactly() -> None:
    t = np.linspace(0, 1, 50)
    pts = np.column_stack([10 * t, t**3 - t, 2 * t**2])  # polynomial in the chord parameter? no: use params
    curve = approximate_curve(pts, 6, params=t)
    assert np.abs(curve.evaluate(t) - pts).max() < 1e-10


def test_smoothing_beats_interpolation_on_noisy_points() -> None:
    rng = np.random.default_rng(0)
    t = np.linspace(0, 1, 400)
    truth = np.column_stack([30 * t, 2 * np.sin(4 * t), np.zeros_like(t)])
    sigma = 0.005
    noisy = truth + rng.normal(0, sigma, truth.shape)
    dense = np.column_stack([30 * np.linspace(0, 1, 3001), 2 * np.sin(4 * np.linspace(0, 1, 3001)), np.zeros(3001)])

    def error(curve):
        return curve.invert(dense[100:-100]).distance.max()

    assert error(smooth_curve(noisy, sigma)) < 0.6 * error(interpolate_curve(noisy))


def test_surface_interpolation_matches_geomdl() -> None:
    uu, vv = np.meshgrid(np.linspace(0, 40, 7), np.linspace(0, 60, 6) ** 1.1, indexing="ij")
    grid = np.stack([uu + 0.3 * vv / 60, vv, np.sin(uu / 9) * np.cos(vv / 13)], axis=-1)
    surf = interpolate_surface(grid, 3, 2)
    ref = gfit.interpolate_surface(grid.reshape(-1, 3).tolist(), 7, 6, 3, 2)
    assert np.abs(np.array(ref.ctrlpts) - surf.control_points.reshape(-1, 3)).max() < 1e-9
    inv = surf.invert(grid.reshape(-1, 3))
    assert inv.distance.max() < 1e-9


def test_scattered_surface_fit_is_exact_for_a_bicubic() -> None:
    rng = np.random.default_rng(1)
    xy = rng.uniform([0, 0], [40, 60], (600, 2))
    z = 1e-4 * (xy[:, 0] ** 3) - 2e-5 * xy[:, 1] ** 2 * xy[:, 0] + 0.1 * xy[:, 1]
    fit = fit_surface(np.column_stack([xy, z]), 6, 7, bounds=(0, 40, 0, 60))
    assert fit.max_mm < 1e-9
    smooth = fit_surface(np.column_stack([xy, z + rng.normal(0, 0.01, z.size)]), 10, 10, smoothing=1e-3)
    assert smooth.rms_mm < 0.02


@pytest.mark.parametrize(
    "points,error,field",
    [
        ([[0, 0], [1, 1], [2, 0]], DegenerateGeometryError, "points"),  # 3 points for a cubic
        ([[0, 0], [1, 1], [1, 1], [2, 0], [3, 3]], DegenerateGeometryError, "points[2]"),
        ([[0, 0], [1, float("nan")], [2, 0], [3, 3]], DegenerateGeometryError, "points[1]"),
        ([[0, 0, 0, 0]] * 5, GeometryError, "points"),
    ],
)
def test_bad_points(points: list, error: type, field: str) -> None:
    with pytest.raises(error) as info:
        interpolate_curve(points)
    assert info.value.field == field


def test_bad_fit_arguments() -> None:
    pts = wiggle(10)
    with pytest.raises(GeometryError) as info:
        approximate_curve(pts, 20)
    assert info.value.field == "n_control" and info.value.value == 20
    with pytest.raises(GeometryError) as info:
        smooth_curve(pts, -1.0)
    assert info.value.field == "sigma_mm"
    with pytest.raises(DegenerateGeometryError):
        fit_surface(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), 8, 8)


def test_grid_surface_fit_and_its_limits() -> None:
    uu, vv = np.meshgrid(np.linspace(0, 40, 9), np.linspace(0, 60, 8), indexing="ij")
    grid = np.stack([uu, vv, 0.01 * uu * vv], axis=-1)  # bilinear: exact for any cubic net
    fit = fit_surface(grid, 5, 4)
    assert fit.max_mm < 1e-9
    with pytest.raises(GeometryError) as info:
        fit_surface(grid, 12, 4)
    assert info.value.field == "n_ctrl_u"
