import numpy as np
import pytest

from app.jetting.qp import solve_fista, solve_lbfgsb

from .helpers import small_qp


@pytest.mark.parametrize("horizon", [1, 3])
def test_gradient_matches_finite_differences(horizon):
    qp, _ = small_qp(horizon=horizon)
    rng = np.random.default_rng(3)
    x = qp.project(rng.random(qp.references.shape))
    _, grad = qp.objective_and_gradient(x)
    d = qp.project(rng.standard_normal(x.shape))
    eps = 1e-6
    fd = (qp.objective(x + eps * d) - qp.objective(x - eps * d)) / (2 * eps)
    assert np.sum(grad * d) == pytest.approx(fd, rel=1e-6)


@pytest.mark.parametrize("horizon, model", [(1, "transport"), (2, "transport"), (1, "seed_diagonal")])
def test_fista_meets_kkt_and_agrees_with_lbfgsb(horizon, model):
    qp, _ = small_qp(horizon=horizon, model=model)
    fast = solve_fista(qp, max_iter=5000, tol=1e-7)
    ref = solve_lbfgsb(qp)
    assert fast.kkt_residual <= 1e-5
    assert ref.kkt_residual <= 1e-3
    gap = (fast.objective - ref.objective) / max(abs(ref.objective), 1e-12)
    assert abs(gap) < 1e-7
    assert float(np.abs(fast.x - ref.x).max()) < 1e-2  # horizon > 1: weakly curved directions
    assert np.all((fast.x >= 0) & (fast.x <= 1))
    assert not fast.x[:, ~qp.free].any()


def test_lipschitz_bound_dominates_the_hessian():
    qp, _ = small_qp()
    rng = np.random.default_rng(0)
    z = np.zeros(qp.references.shape)
    _, g0 = qp.objective_and_gradient(z)
    v = qp.project(rng.random(z.shape))
    for _ in range(30):  # power iteration on the Hessian restricted to free cells
        _, gv = qp.objective_and_gradient(v)
        hv = gv - g0
        v = hv / np.linalg.norm(hv)
    _, gv = qp.objective_and_gradient(v)
    assert np.sum(v * (gv - g0)) <= qp.lipschitz() * (1 + 1e-9)


def test_separable_case_has_the_closed_form_solution():
    qp, _ = small_qp(dpi=300.0, model="seed_diagonal", steps=0)  # G = k00 I: separable
    k = qp.model.kernel.heights_mm[0, 0] / qp.scale_mm
    e0 = (qp.h0 - qp.references[0]) / qp.scale_mm
    w = qp.stage_weights[0]
    exact = np.clip(-w * k * e0 / (w * k * k + qp.rho), 0, 1) * qp.free
    sol = solve_fista(qp, tol=1e-9)
    np.testing.assert_allclose(sol.x[0], exact, atol=1e-8)
