"""Surface fit on analytic surfaces from noisy measurements (truth known exactly)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.geometry.nurbs_surface import NurbsSurface
from app.probing.grid import ProbeRegion, plan_probe_grid
from app.reconstruction.surface_fit import (
    GridHoleError,
    HeightGrid,
    SurfaceFitError,
    SurfaceFitParams,
    fit_surface,
    grid_from_plan,
)

R = 50.0
NOISE = 0.005


def _sphere(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.sqrt(R**2 - x**2 - y**2)


def _max_sphere_error(surface: NurbsSurface) -> float:
    (u0, u1), (v0, v1) = surface.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, 61), np.linspace(v0, v1, 61), indexing="ij")
    p = surface.evaluate(uu.ravel(), vv.ravel())
    return float(np.abs(np.linalg.norm(p, axis=1) - R).max())


def _noisy_grid(seed: int = 7, n: int = 20) -> HeightGrid:
    plan = plan_probe_grid(ProbeRegion(-20, 20, -20, 20), n, n)
    rng = np.random.default_rng(seed)
    x, y = plan.points_xy.T
    return grid_from_plan(plan, _sphere(x, y) + rng.normal(0, NOISE, x.size))


def test_probe_plan_is_a_serpentine_covering_each_cell_once() -> None:
    plan = plan_probe_grid(ProbeRegion(0, 30, 0, 10), 4, 3)
    assert {tuple(ij) for ij in plan.index.tolist()} == {(i, j) for i in range(4)
                                                         for j in range(3)}
    steps = np.linalg.norm(np.diff(plan.points_xy, axis=0), axis=1)
    assert steps.max() == pytest.approx(10.0)  # never a long return stroke
    z = np.arange(12.0)
    grid = grid_from_plan(plan, z)
    assert grid.z[plan.index[5, 0], plan.index[5, 1]] == 5.0


def test_least_squares_fit_meets_the_10um_goal_on_a_noisy_20x20_sphere() -> None:
    fit = fit_surface(_noisy_grid(), SurfaceFitParams())
    assert _max_sphere_error(fit.surface) <= 0.010
    # residuals are the measurement noise: RMS close to 5 um
    assert 0.003 < fit.residual_rms_mm < 0.007
    assert fit.removed_points.shape == (0, 3)
    assert fit.summary()["control_points"] == list(fit.control_points)


def test_interpolating_fit_passes_through_the_points() -> None:
    grid = _noisy_grid()
    fit = fit_surface(grid, SurfaceFitParams(method="interpolate", remove_bad_points=False))
    assert fit.residual_max_mm < 1e-6
    assert fit.control_points == (20, 20)


def test_five_point_cubic_smoothing_then_fit() -> None:
    fit = fit_surface(_noisy_grid(), SurfaceFitParams(method="interpolate",
                                                      smoothing="five_point_cubic"))
    plain = fit_surface(_noisy_grid(), SurfaceFitParams(method="interpolate"))
    assert _max_sphere_error(fit.surface) < _max_sphere_error(plain.surface)


def test_bad_points_are_removed_and_refilled() -> None:
    grid = _noisy_grid()
    z = grid.z.copy()
    z[5, 6] += 0.4
    fit = fit_surface(HeightGrid(grid.x, grid.y, z), SurfaceFitParams())
    assert fit.removed_points.shape == (1, 3)
    assert fit.removed_points[0, :2] == pytest.approx([grid.x[5], grid.y[6]])
    assert fit.filled_holes == 1
    assert _max_sphere_error(fit.surface) <= 0.010


def test_nan_grid_is_a_typed_error_or_a_documented_repair() -> None:
    grid = _noisy_grid()
    z = grid.z.copy()
    z[2, 3] = np.nan
    z[10, 11] = np.nan
    holed = HeightGrid(grid.x, grid.y, z)
    with pytest.raises(GridHoleError) as info:
        fit_surface(holed, SurfaceFitParams())
    assert info.value.field == "grid.z"
    assert info.value.value["cells"][0] == [2, 3] and info.value.value["missing"] == 2
    fit = fit_surface(holed, SurfaceFitParams(hole_policy="fill"))
    assert fit.filled_holes == 2 and _max_sphere_error(fit.surface) <= 0.010


def test_scattered_cmm_points() -> None:
    rng = np.random.default_rng(11)
    xy = rng.uniform(-20, 20, (600, 2))
    pts = np.column_stack([xy, _sphere(xy[:, 0], xy[:, 1]) + rng.normal(0, NOISE, 600)])
    direct = fit_surface(pts, SurfaceFitParams())
    assert direct.fitted_grid is None
    assert _max_sphere_error(direct.surface) <= 0.02  # random gaps near the edges
    resampled = fit_surface(pts, SurfaceFitParams(resample_shape=(15, 15),
                                                  smoothing="five_point_cubic"))
    assert resampled.fitted_grid is not None and resampled.fitted_grid.z.shape == (15, 15)
    assert _max_sphere_error(resampled.surface) <= 0.03


def test_bad_inputs_name_the_field() -> None:
    with pytest.raises(SurfaceFitError) as info:
        SurfaceFitParams(method="magic")  # type: ignore[arg-type]
    assert info.value.field == "params.method"
    with pytest.raises(SurfaceFitError) as info:
        fit_surface(np.zeros((10, 2)), SurfaceFitParams())
    assert info.value.field == "points"
    with pytest.raises(SurfaceFitError) as info:
        HeightGrid(np.arange(3.0), np.arange(4.0), np.zeros((4, 3)))
    assert info.value.field == "grid.z"
    with pytest.raises(SurfaceFitError) as info:
        HeightGrid(np.array([0.0, 0.0, 1.0]), np.arange(4.0), np.zeros((3, 4)))
    assert info.value.field == "grid.x"


# ------------------------------------------------- degenerate point sets: typed errors
def _on_a_line(k: int = 40) -> np.ndarray:
    t = np.arange(k, dtype=float)
    return np.column_stack([t, 2.0 * t, np.ones(k)])


def _lattice(n: int, copies: int = 1) -> np.ndarray:
    i = np.arange(n * n)
    return np.tile(np.column_stack([i % n, i // n, 0.01 * (i % n) ** 2]), (copies, 1)).astype(float)


@pytest.mark.parametrize(("name", "points", "needle"), [
    ("collinear", _on_a_line(), "one line"),
    ("identical", np.tile([[0.0, 0.0, 1.0]], (40, 1)), "1 distinct"),
    ("few positions", _lattice(3, copies=5), "9 distinct"),
])
@pytest.mark.parametrize("remove_bad_points", [True, False])
@pytest.mark.parametrize("resample_shape", [None, (10, 10)])
def test_degenerate_points_are_a_typed_error(name, points, needle, remove_bad_points,
                                             resample_shape) -> None:
    """Formerly a bare numpy LinAlgError (or, for collinear points, a meaningless fit)."""
    params = SurfaceFitParams(remove_bad_points=remove_bad_points,
                              resample_shape=resample_shape)
    with pytest.raises(SurfaceFitError) as info:
        fit_surface(points, params)
    assert info.value.field == "points" and needle in info.value.message, name


def test_repeated_positions_cannot_be_resampled_but_can_be_fitted() -> None:
    points = _lattice(7, copies=2)  # every (x, y) measured twice
    for remove_bad_points in (True, False):
        with pytest.raises(SurfaceFitError) as info:
            fit_surface(points, SurfaceFitParams(resample_shape=(10, 10),
                                                 remove_bad_points=remove_bad_points))
        assert info.value.field == "points" and info.value.value == {"repeats": 49}
    # a least-squares fit of the scattered points takes both heights (here equal)
    fit = fit_surface(points, SurfaceFitParams(remove_bad_points=False, control_points=(4, 4)))
    assert fit.residual_max_mm < 1e-9  # z = 0.01 x^2 is in the cubic spline space


def test_points_on_two_lines_are_a_typed_error_not_a_singular_matrix() -> None:
    """Two parallel lines span an area, but a bicubic height fit over them is singular."""
    t = np.linspace(0.0, 10.0, 20)
    points = np.vstack([np.column_stack([t, np.full(20, y), np.ones(20)]) for y in (0.0, 1.0)])
    for remove_bad_points in (True, False):
        with pytest.raises(SurfaceFitError) as info:
            fit_surface(points, SurfaceFitParams(remove_bad_points=remove_bad_points))
        assert info.value.field == "points"


@given(st.integers(16, 60), st.floats(-3.0, 3.0), st.floats(0.1, 10.0), st.integers(1, 3),
       st.booleans(), st.booleans())
@settings(max_examples=25, deadline=None)
def test_any_collinear_or_repeated_point_set_is_a_typed_error(k, angle, step, copies,
                                                             remove_bad_points,
                                                             resample) -> None:
    t = step * np.arange(k)
    line = np.column_stack([t * np.cos(angle) + 3.0, t * np.sin(angle) - 1.0, 0.1 * t])
    params = SurfaceFitParams(remove_bad_points=remove_bad_points,
                              resample_shape=(8, 8) if resample else None)
    with pytest.raises(SurfaceFitError) as info:
        fit_surface(np.tile(line, (copies, 1)), params)
    assert info.value.field == "points"


def test_grid_whose_valid_heights_lie_on_one_line_is_a_typed_error() -> None:
    z = np.ones((2, 20))
    z[1] = np.nan  # half the grid missing: one valid column
    grid = HeightGrid(np.array([0.0, 1.0]), np.linspace(0.0, 1.0, 20), z)
    for remove_bad_points in (True, False):
        with pytest.raises(SurfaceFitError) as info:
            fit_surface(grid, SurfaceFitParams(hole_policy="fill", degree=1,
                                               remove_bad_points=remove_bad_points))
        assert info.value.field == "grid.z" and "one line" in info.value.message
