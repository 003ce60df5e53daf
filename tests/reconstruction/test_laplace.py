"""The Laplace sd and covariance against a Gaussian's: exact for a quadratic negative log density."""

from __future__ import annotations

import numpy as np
import pytest

from app.reconstruction.laplace import correlation, covariance_sd, laplace_covariance


def test_the_laplace_sd_of_a_gaussian_is_its_sd_and_a_bound_parameter_is_held_fixed():
    a = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])   # the precision
    mu = np.array([0.3, -1.0, 2.0])

    def objective(t: np.ndarray) -> float:
        return float(0.5 * (t - mu) @ a @ (t - mu))

    free = covariance_sd(laplace_covariance(objective, mu, ("", "", ""), 1e-3))
    assert np.allclose(free, np.sqrt(np.diag(np.linalg.inv(a))), rtol=1e-6)
    held = covariance_sd(laplace_covariance(objective, mu, ("", "lower", ""), 1e-3))
    sub = np.linalg.inv(a[np.ix_([0, 2], [0, 2])])
    assert np.isnan(held[1]) and np.allclose(held[[0, 2]], np.sqrt(np.diag(sub)), rtol=1e-6)
    assert np.isnan(covariance_sd(laplace_covariance(objective, mu, ("upper", "lower", "upper"), 1e-3))).all()


def test_the_laplace_covariance_of_a_gaussian_is_its_inverse_precision_and_a_bound_parameter_is_held_fixed():
    a = np.array([[4.0, 3.0, 0.5], [3.0, 3.0, 0.2], [0.5, 0.2, 2.0]])   # the precision: strongly correlated 0 and 1
    mu = np.array([0.3, -1.0, 2.0])

    def objective(t: np.ndarray) -> float:
        return float(0.5 * (t - mu) @ a @ (t - mu))

    cov = laplace_covariance(objective, mu, ("", "", ""), 1e-3)
    inv = np.linalg.inv(a)
    assert np.allclose(cov, inv, rtol=1e-6, atol=1e-9)
    assert correlation(cov, 0, 1) == pytest.approx(inv[0, 1] / np.sqrt(inv[0, 0] * inv[1, 1]), rel=1e-6)
    assert correlation(cov, 0, 1) < -0.5   # a positive cross-precision: negatively correlated
    held = laplace_covariance(objective, mu, ("", "", "upper"), 1e-3)
    assert np.isnan(held[2]).all() and np.isnan(held[:, 2]).all()
    assert np.allclose(held[:2, :2], np.linalg.inv(a[:2, :2]), rtol=1e-6)
    assert np.isnan(correlation(held, 0, 2))
