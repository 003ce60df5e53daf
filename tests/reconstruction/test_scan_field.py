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


def test_per_sample_noise_matches_the_exact_heteroscedastic_posterior():
    """Sensor samples (0.5 um) and probe touches (5 um) together: the weighted inducing-point
    fit against the exact GP with the noise of each point on the diagonal."""
    from app.probing.deviation_prior import prior_covariance, prior_variance

    rng = np.random.default_rng(2)
    prior = DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.0005)
    xy = rng.uniform([0, 0], [40, 30], (400, 2))
    noise = np.where(np.arange(400) < 380, 0.0005, 0.005)
    dz = _field(xy) + rng.normal(0, noise)
    center = np.array([20.0, 15.0])
    sites = Sites(xy, np.zeros_like(xy))
    sparse = fit_scan_field(prior, sites, dz, center, noise_mm=noise)
    k = prior_covariance(prior, sites, sites, center) + np.diag(noise ** 2)
    q = Sites(rng.uniform([2, 2], [38, 28], (100, 2)), np.zeros((100, 2)))
    kq = prior_covariance(prior, q, sites, center)
    mean = kq @ np.linalg.solve(k, dz)
    sd = np.sqrt(prior_variance(prior, q, center) - np.sum(kq.T * np.linalg.solve(k, kq.T), axis=0))
    assert np.abs(sparse.deviation(q) - mean).max() < 2e-5
    assert np.abs(sparse.posterior.sd(q) - sd).max() < 1e-4


def test_gap_sites_fall_in_the_hole_of_the_samples():
    from app.geometry.traces import TracePolyline
    from app.reconstruction.scan_field import gap_sites

    prior = DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.0005)
    y = np.arange(0.0, 40.0, 0.25)
    keep = (y < 10) | (y > 30)  # the sensor saw nothing over y in [10, 30]
    xy = np.column_stack([np.full(keep.sum(), 10.0), y[keep]])
    fit = fit_scan_field(prior, Sites(xy, np.zeros_like(xy)), _field(xy), np.array([10.0, 20.0]))
    path = TracePolyline.from_points(np.column_stack([np.full(81, 10.0), np.linspace(0, 40, 81), np.zeros(81)]))
    sites, owner = gap_sites(fit, [path], 4.0, 0.005, 5)
    assert 1 <= len(sites.xy) <= 5 and (owner == 0).all()
    assert ((sites.xy[:, 1] > 10) & (sites.xy[:, 1] < 30)).all() and abs(sites.xy[0, 1] - 20.0) < 1.0
    assert len(sites.xy) == 1 or np.diff(np.sort(sites.xy[:, 1])).min() >= 15.0 / 4 - 1e-9
    none, _ = gap_sites(fit, [path], 4.0, 1.0, 5)  # a loose target: nothing to touch
    assert len(none.xy) == 0


def test_a_checked_scan_field_reads_back_bit_for_bit():
    from app.reconstruction.field_trust import with_bound
    from app.reconstruction.scan_field import ScanFieldCheck, verify_touches
    from app.reconstruction.scan_field_store import scan_check_from_npz, scan_check_npz

    rng = np.random.default_rng(3)
    prior = DeviationPrior(amplitude_mm=0.15, wavelength_mm=15.0, sigma_mm=0.0005)
    xy = rng.uniform([0, 0], [40, 30], (600, 2))
    fit = fit_scan_field(prior, Sites(xy, rng.normal(0, 0.1, (600, 2))), _field(xy), np.array([20.0, 15.0]))
    v = Sites(np.array([[5.0, 5.0], [30.0, 20.0]]), np.zeros((2, 2)))
    check = with_bound(ScanFieldCheck(fit, None, verify_touches(fit, v, _field(v.xy) + 0.001, np.array([0, 1]), 4.0,
                                                                0.001), 4.0, 0.005, touch_sigma_mm=0.001), [0.002])
    back = scan_check_from_npz(scan_check_npz(check))
    q = Sites(rng.uniform([2, 2], [38, 28], (50, 2)), rng.normal(0, 0.1, (50, 2)))
    assert np.array_equal(back.fit.deviation(q), check.fit.deviation(q))
    assert np.array_equal(back.fit.posterior.sd(q), check.fit.posterior.sd(q))
    assert back.as_dict()["verification"] == check.as_dict()["verification"]
    assert back.noise_allowance_mm == 0.004 and back.target_mm == 0.005 and back.bound_mm != back.bound_mm  # NaN
