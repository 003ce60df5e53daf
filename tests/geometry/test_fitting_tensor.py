"""The surface least-squares solvers: the tensor-product grid solve and the banded normal
equations give the dense least-squares answer, and a net as large as the grid interpolates.

The old solver (SuperLU on the (n_u n_v)-unknown normal equations, ``_solve_normal``) is kept
for curves; here it is the reference the new solvers must match on small cases."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.interpolate import BSpline

from app.geometry.fitting import (
    _row_kron,
    _second_difference,
    _solve_net,
    _solve_normal,
    _solve_tensor_grid,
    approximation_knots,
    fit_surface,
    grid_knots,
    grid_parameters,
)
from app.geometry.tolerance import DEFAULT_TOLERANCE


def wavy_grid(nu: int, nv: int, seed: int = 0) -> np.ndarray:
    """(nu, nv, 3) grid on uneven x, y lines with a non-polynomial height (mm)."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.uniform(0.5, 1.5, nu))
    y = np.cumsum(rng.uniform(0.5, 1.5, nv))
    xx, yy = np.meshgrid(x, y, indexing="ij")
    return np.stack([xx, yy, 3 + np.sin(xx / 4) * np.cos(yy / 5) + 0.01 * xx * yy], axis=-1)


def designs(grid: np.ndarray, mu: int, mv: int, pu: int, pv: int, knots=grid_knots):
    u = grid_parameters(grid, 0, DEFAULT_TOLERANCE, "grid")
    v = grid_parameters(grid, 1, DEFAULT_TOLERANCE, "grid")
    tu, tv = knots(u, mu, pu), knots(v, mv, pv)
    return BSpline.design_matrix(u, tu, pu), BSpline.design_matrix(v, tv, pv)


@pytest.mark.parametrize(("nu", "nv", "mu", "mv", "pu", "pv"), [
    (12, 9, 6, 5, 3, 3), (20, 15, 8, 11, 3, 2), (9, 9, 9, 9, 3, 3), (16, 7, 10, 4, 2, 1), (30, 25, 12, 12, 5, 3),
])
def test_the_tensor_grid_solve_is_the_dense_least_squares_answer(nu, nv, mu, mv, pu, pv):
    grid = wavy_grid(nu, nv, seed=nu)
    bu, bv = designs(grid, mu, mv, pu, pv)
    new = _solve_tensor_grid(bu, bv, grid, "grid")
    dense = np.kron(bu.toarray(), bv.toarray())  # row i*nv + j, column a*mv + b
    reference = np.linalg.lstsq(dense, grid.reshape(-1, 3), rcond=None)[0].reshape(mu, mv, 3)
    assert np.abs(new - reference).max() < 1e-9
    old = _solve_normal(sp.csc_array(dense), grid.reshape(-1, 3), "grid")  # the solver fit_surface used before
    assert np.abs(new - old.reshape(mu, mv, 3)).max() < 1e-9


@pytest.mark.parametrize(("mu", "mv", "smoothing"), [(6, 6, 0.0), (7, 5, 1e-3), (5, 9, 0.1), (8, 8, 1.0)])
def test_the_banded_normal_solve_matches_the_old_sparse_solve(mu, mv, smoothing):
    rng = np.random.default_rng(mu * 10 + mv)
    uv = rng.uniform(0, 1, (400, 2))
    pts = np.column_stack([uv * 40, 2 + np.sin(uv[:, 0] * 5) + uv[:, 1] ** 3])
    tu = np.concatenate([np.zeros(3), np.linspace(0, 1, mu - 2), np.ones(3)])
    tv = np.concatenate([np.zeros(3), np.linspace(0, 1, mv - 2), np.ones(3)])
    design = _row_kron(BSpline.design_matrix(uv[:, 0], tu, 3), BSpline.design_matrix(uv[:, 1], tv, 3))
    penalty = None
    if smoothing:
        du = sp.kron(_second_difference(mu), sp.eye(mv))
        dv = sp.kron(sp.eye(mu), _second_difference(mv))
        pen = (du.T @ du + dv.T @ dv).tocsc()
        penalty = smoothing * (design.multiply(design)).sum() / pen.diagonal().sum() * pen
    old = _solve_normal(design.tocsc(), pts, "points", penalty)
    new = _solve_net(design, pts, mu, mv, smoothing, "points")
    assert np.abs(new - old).max() < 1e-9


def test_a_net_as_large_as_the_grid_interpolates_it():
    """With the old Eq. 9.68 knots a 50 x 50 net on a 50 x 50 grid had a collocation matrix of
    condition 1e19: control points of 1e22 mm and a residual of 995 mm.  grid_knots are the
    interpolation knots there: the surface passes through every grid point."""
    grid = wavy_grid(50, 50, seed=3)
    fit = fit_surface(grid, 50, 50)
    assert fit.max_mm < 1e-9
    assert np.abs(fit.surface.control_points).max() < 10 * np.abs(grid).max()
    u = grid_parameters(grid, 0, DEFAULT_TOLERANCE, "grid")
    for n in (50, 49, 47, 40, 25, 8, 4):
        assert np.linalg.cond(BSpline.design_matrix(u, grid_knots(u, n, 3), 3).toarray()) < 50
    assert np.linalg.cond(BSpline.design_matrix(u, approximation_knots(u, 47, 3), 3).toarray()) > 1e6


def test_grid_knots_are_clamped_increasing_and_the_interpolation_knots_at_full_size():
    u = grid_parameters(wavy_grid(30, 4), 0, DEFAULT_TOLERANCE, "grid")
    for n in (4, 10, 29, 30):
        t = grid_knots(u, n, 3)
        assert t.size == n + 4 and np.all(np.diff(t) >= 0)
        assert np.all(t[:4] == 0) and np.all(t[-4:] == 1)
    from app.geometry.fitting import averaged_knots

    assert np.allclose(grid_knots(u, 30, 3), averaged_knots(u, 3), atol=1e-15)


def test_a_bilinear_surface_is_reproduced_by_every_net():
    """On an even grid a bilinear height has straight grid lines (uniform chord parameters):
    it lies in the spline space of every cubic net, so every fit is exact."""
    x = np.linspace(0, 40, 60)
    xx, yy = np.meshgrid(x, x[:45], indexing="ij")
    grid = np.stack([xx, yy, 2 + 0.03 * xx - 0.02 * yy + 1e-3 * xx * yy], axis=-1)
    for mu, mv in ((4, 4), (10, 7), (60, 45)):
        assert fit_surface(grid, mu, mv).max_mm < 1e-9
