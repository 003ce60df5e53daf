"""The hyperparameters' uncertainty in a bound: the joint ellipse against its analytic
quantile for a bound log-linear in (log A, log lambda), and against the corner."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.reconstruction.hyper_bound import ellipse_max, ellipse_points, log_covariance, worst_point


def log_linear(b0: np.ndarray, gradients: np.ndarray, seen: list[np.ndarray] | None = None):
    """bound_of(d) (T,) = b0 (T,) exp(gradients (T, 2) . d): each trace's log bound linear in the offsets."""
    def bound_of(d: np.ndarray) -> np.ndarray:
        if seen is not None:
            seen.append(np.array(d))
        out: np.ndarray = b0 * np.exp(gradients @ d)
        return out
    return bound_of


@pytest.mark.parametrize("sd, rho, g", [((0.4, 0.15), 0.82, (1.0, -1.5)), ((0.3, 0.1), 0.0, (1.0, -1.0)),
                                        ((0.2, 0.2), -0.5, (0.7, -2.0)), ((0.35, 0.08), 0.95, (1.0, -0.3))])
def test_a_log_linear_bound_is_taken_at_its_one_sided_quantile_on_the_ellipse(sd, rho, g):
    """log bound = log b0 + g . d: its largest over the r-sd ellipse is log b0 + r sqrt(g' S g)
    (the linear function's quantile at Phi(r)), reached at a point of the ellipse (Mahalanobis r)."""
    cov = log_covariance(sd, rho)
    assert cov[0, 1] == pytest.approx(rho * sd[0] * sd[1]) and np.allclose(np.diag(cov), np.square(sd))
    g = np.array(g)
    seen: list[np.ndarray] = []
    out = ellipse_max(log_linear(np.array([0.004]), g[None, :], seen), cov, 3.0)
    assert out[0] == pytest.approx(0.004 * math.exp(3.0 * math.sqrt(g @ cov @ g)), rel=1e-9)
    assert len(seen) == 4
    for d in seen[1:]:
        assert float(d @ np.linalg.solve(cov, d)) == pytest.approx(9.0, rel=1e-9)


def test_the_ellipse_is_never_above_the_corner_at_as_many_sd_and_is_the_corner_at_correlation_minus_one():
    """The r-sd ellipse lies inside its bounding box, whose unfavourable corner (A r sd up,
    lambda r sd down) is the corner's: for a log-linear bound growing with A and as lambda
    shortens the ellipse's value is at most the corner's, and equal to it where the two are
    perfectly anti-correlated (the ellipse is the box's diagonal through that corner)."""
    rng = np.random.default_rng(1)
    for _ in range(200):
        sd = tuple(rng.uniform(0.02, 0.5, 2))
        rho = float(rng.uniform(-1.0, 1.0))
        g = np.array([rng.uniform(0.0, 1.5), -rng.uniform(0.0, 3.0)])
        cov = log_covariance(sd, rho)
        corner = 0.005 * math.exp(g @ (2.0 * np.array([sd[0], -sd[1]])))
        assert ellipse_max(log_linear(np.array([0.005]), g[None, :]), cov, 2.0)[0] <= corner * (1 + 1e-12)
        anti = ellipse_max(log_linear(np.array([0.005]), g[None, :]), log_covariance(sd, -1.0), 2.0)[0]
        assert anti == pytest.approx(corner, rel=1e-12)


def test_each_trace_takes_its_own_largest_and_a_parameter_on_a_bound_is_held():
    """Two traces with different gradients: each is the largest of its own values at the
    evaluated points (never below its value at the estimate).  The wavelength without an sd
    (on a bound): only the amplitude moves, r of its sd up."""
    cov = log_covariance((0.3, 0.1), 0.6)
    grads = np.array([[1.0, -0.2], [0.2, -3.0]])
    seen: list[np.ndarray] = []
    out = ellipse_max(log_linear(np.array([0.004, 0.003]), grads, seen), cov, 3.0)
    values = np.array([[0.004, 0.003] * np.exp(grads @ d) for d in seen])
    assert np.array_equal(out, values.max(axis=0)) and (out >= [0.004, 0.003]).all()
    held = log_covariance((0.3, math.nan), 0.6)
    assert np.array_equal(held, [[0.09, 0.0], [0.0, 0.0]])
    assert ellipse_points(held, 3.0)[1] == pytest.approx([0.0, 0.0])
    one = ellipse_max(log_linear(np.array([0.004]), np.array([[1.0, -1.0]])), held, 3.0)
    assert one[0] == pytest.approx(0.004 * math.exp(0.9), rel=1e-12)
    assert np.array_equal(worst_point(np.zeros((2, 2)), np.array([1.0, -1.0])), [0.0, 0.0])
