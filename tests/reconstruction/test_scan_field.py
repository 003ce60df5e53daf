"""The inducing-point scan field against the exact GP and a known field."""

from __future__ import annotations

import numpy as np

from app.probing.deviation_prior import DeviationPrior, Sites, fit_posterior
from app.reconstruction.scan_field import fit_scan_field, predicted_sd
from app.reconstruction.scan_samples import block_average


def _field(p: np.ndarray) -> np.ndarray:
    return 0.05 * np.sin(2 * np.pi * p[:, 0] / 20) * np.cos(2 * np.pi * p[:, 1] / 25) \
        + 0.03 * np.cos(2 * np.pi * (p[:, 0] + p[:, 1]) / 30) + 0.02


def test_the_inducing_point_fit_matches_the_exact_posterior():
    rng = np.random.default_rng(0)
    prior = DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.001)
    xy = rng.uniform([0, 0], [40, 30], (500, 2))
    sites = Sites(xy, np.zeros_like(xy))
    dz = _field(xy) + rng.normal(0, 0.001, len(xy))
    center = np.array([20.0, 15.0])
    sparse = fit_scan_field(prior, sites, dz, center)
    exact = fit_posterior(prior, sites, dz, center)
    q = rng.uniform([2, 2], [38, 28], (200, 2))
    qs = Sites(q, np.zeros_like(q))
    assert np.abs(sparse.deviation(qs) - exact.mean(qs)).max() < 2e-5
    assert np.abs(sparse.posterior.sd(qs) - exact.sd(qs)).max() < 1e-4
    assert np.abs(sparse.deviation(qs) - _field(q)).max() < 0.002
    assert np.allclose(predicted_sd(prior, sites, center, qs), sparse.posterior.sd(qs), atol=1e-9)


def test_a_spike_is_dropped_and_does_not_bend_the_field():
    rng = np.random.default_rng(1)
    prior = DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.0005)
    xy = rng.uniform([0, 0], [30, 30], (1000, 2))
    dz = _field(xy) + rng.normal(0, 0.0005, len(xy))
    dz[7] += 0.2
    fit = fit_scan_field(prior, Sites(xy, np.zeros_like(xy)), dz, np.array([15.0, 15.0]))
    assert 7 in fit.outliers and len(fit.outliers) < 10
    assert abs(fit.deviation(Sites(xy[7:8], np.zeros((1, 2))))[0] - _field(xy[7:8])[0]) < 0.001


def test_block_average_means_runs_of_k():
    xy = np.arange(14, dtype=float).reshape(7, 2)
    mxy, mz = block_average(xy, np.arange(7, dtype=float), 3)
    assert np.allclose(mz, [1.0, 4.0, 6.0]) and np.allclose(mxy[0], [2.0, 3.0])


def test_exposure_positions_shift_sampled_positions_back_by_the_time_offset():
    from app.reconstruction.scan_samples import exposure_positions

    t = np.arange(100) * 0.001
    sampled = np.column_stack([5.0 + 50.0 * t, np.full(100, 2.0), 10.0 - 3.0 * t])  # 50 mm/s in x, -3 in z
    got = exposure_positions(t, sampled, 0.004)
    assert np.allclose(got[4:, 0], 5.0 + 50.0 * (t[4:] - 0.004))
    assert np.allclose(got[4:, 2], 10.0 - 3.0 * (t[4:] - 0.004))
    assert np.allclose(got[:4], sampled[0])  # before the first sample: held there
    assert np.allclose(exposure_positions(t, sampled, 0.0), sampled)
