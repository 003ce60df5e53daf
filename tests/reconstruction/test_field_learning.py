"""The deviation prior learned from the touches: type-II ML against fields drawn from a
known prior (the analytic truth), its uncertainty, and the leave-one-out misfit test."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import check_grad

from app.probing.deviation_prior import DeviationPrior, Sites
from app.reconstruction.field_learning import (
    LearningError,
    _Likelihood,
    learn_prior,
    log_marginal_likelihood,
    loo_check,
)
from tests.helpers.field_draws import draw

TRUTH = DeviationPrior(amplitude_mm=0.12, wavelength_mm=10.0, sigma_mm=0.004)
USER = DeviationPrior()  # the defaults: A 0.2 mm, lambda 20 mm, 1 um noise


def test_the_gradient_is_the_likelihoods():
    sites, center, dz = draw(TRUTH, 30, 1)
    lk = _Likelihood(USER, sites, dz, center)
    theta = np.log([0.1, 12.0, 0.003])
    assert check_grad(lk.value, lambda t: lk(t)[1], theta) < 1e-4 * np.linalg.norm(lk(theta)[1])
    assert math.isclose(-lk.value(np.log([0.2, 20.0, 0.001])), log_marginal_likelihood(USER, sites, dz, center))


def test_the_kernel_from_its_upper_triangle_is_the_full_matrix_and_the_value_alone_is_the_value():
    """The likelihood evaluates its Bessel functions (from their tables) on the upper triangle
    and mirrors them: the covariance is symmetric bit for bit and within 1e-14 x rms^2 of the
    kernel evaluated on every pair by scipy (an independent reference: jinc(x) = 2 J1(x) / x
    on the full distance matrix), its wavelength derivative within 1e-13 of 2 J2(x) by scipy's
    general-order jv; the value without the gradient is the same number as the value with it."""
    from scipy.special import j1, jv

    from app.probing.deviation_prior import placement_basis

    sites, center, dz = draw(TRUTH, 40, 2)
    lk = _Likelihood(USER, sites, dz, center)
    theta = np.log([0.1, 12.0, 0.003])
    x = np.hypot(*(sites.xy[:, None, :] - sites.xy[None, :, :]).transpose(2, 0, 1)) * (2 * np.pi / math.exp(theta[1]))
    jinc = np.where(x < 1e-6, 1.0 - x ** 2 / 8.0, 2.0 * j1(np.where(x < 1e-6, 1.0, x)) / np.where(x < 1e-6, 1.0, x))
    basis = placement_basis(sites, center) * USER.basis_sd
    rms2 = (math.exp(theta[0]) / USER.peak_factor) ** 2
    expected = rms2 * jinc + basis @ basis.T
    expected[np.diag_indices_from(expected)] += math.exp(2 * theta[2])
    covariance = lk.covariance(theta)
    assert np.array_equal(covariance, covariance.T) and np.abs(covariance - expected).max() < 1e-14 * rms2
    k, _, djinc, _, _ = lk.parts(theta)
    assert np.array_equal(k, covariance) and np.abs(djinc - 2.0 * jv(2, x)).max() < 1e-13
    for t in (theta, np.log([0.2, 20.0, 0.001]), np.log([0.05, 5.0, 0.01])):
        assert lk.value(t) == lk(t)[0]


def test_the_restricted_likelihoods_gradient_and_its_blindness_to_an_offset_and_tilts():
    sites, center, dz = draw(TRUTH, 30, 1)
    lk = _Likelihood(USER, sites, dz, center, "reml")
    theta = np.log([0.1, 12.0, 0.003])
    assert check_grad(lk.value, lambda t: lk(t)[1], theta) < 1e-4 * np.linalg.norm(lk(theta)[1])
    for t in (theta, np.log([0.2, 20.0, 0.001]), np.log([0.05, 5.0, 0.01])):
        assert math.isclose(lk.value(t), lk(t)[0], rel_tol=1e-9)   # the value alone is the value
    # REML integrates the offset and the tilts out: adding any of them changes nothing, while
    # the marginal likelihood (their tolerances as prior sd) sees them
    x = sites.xy - center
    shifted = dz + 0.3 + 0.01 * x[:, 0] - 0.02 * x[:, 1]
    assert math.isclose(_Likelihood(USER, sites, shifted, center, "reml").value(theta), lk.value(theta),
                        rel_tol=1e-9, abs_tol=1e-9)
    ml = _Likelihood(USER, sites, dz, center)
    assert _Likelihood(USER, sites, shifted, center).value(theta) > ml.value(theta) + 10.0
    assert math.isclose(-lk.value(np.log([0.2, 20.0, 0.001])),
                        log_marginal_likelihood(USER, sites, dz, center, method="reml"))
    with pytest.raises(LearningError):
        learn_prior(USER, sites, dz, center, method="map")


@pytest.mark.parametrize("method", ["ml", "reml"])
@pytest.mark.parametrize("seed", [3, 4, 5])
def test_amplitude_wavelength_and_noise_recovered_within_20_percent_from_60_touches(seed, method):
    sites, center, dz = draw(TRUTH, 60, seed, pairs=12)
    learned = learn_prior(USER, sites, dz, center, method=method)
    got = learned.prior
    assert learned.method == method and learned.as_dict()["method"] == method
    assert abs(got.amplitude_mm / TRUTH.amplitude_mm - 1) < 0.2
    assert abs(got.wavelength_mm / TRUTH.wavelength_mm - 1) < 0.2
    assert abs(got.sigma_mm / TRUTH.sigma_mm - 1) < 0.5   # noise from 12 repeated pairs: a coarser figure
    # the stated uncertainty covers the truth (3 sd in the log parameters) and the model fits
    truth = np.log([TRUTH.amplitude_mm, TRUTH.wavelength_mm])
    fitted = np.log([got.amplitude_mm, got.wavelength_mm])
    assert np.all(np.abs(fitted - truth) < 3 * learned.log_sd[:2])
    assert not learned.misfit and learned.log_likelihood >= learned.start_log_likelihood


def test_a_field_shorter_than_the_shortest_wavelength_allowed_is_a_misfit():
    short = DeviationPrior(amplitude_mm=0.12, wavelength_mm=2.0, sigma_mm=0.001)
    sites, center, dz = draw(short, 40, 7)
    learned = learn_prior(USER, sites, dz, center)
    assert learned.misfit
    assert learned.at_bound[1] == "lower" or learned.prior.sigma_mm > 5 * USER.sigma_mm


@pytest.mark.parametrize("seed", [13, 29, 30, 40])
def test_touches_that_are_noise_about_the_rigid_terms_are_no_misfit(seed):
    # a part 30 um high everywhere, touched with 1 um noise and read to the readout's 1 um: the
    # learning may park a noise-sized field on the shortest wavelength (these seeds do), but it
    # is no likelier than noise and the touches scatter as the probe does: the model holds
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.0, 0.0], [60.0, 40.0], (40, 2))
    sites = Sites(xy, rng.normal(0.0, 0.1, (40, 2)))
    dz = np.round(9.0 + 0.03 + rng.normal(0.0, 0.001, 40), 3) - 9.0
    learned = learn_prior(DeviationPrior(amplitude_mm=0.01, wavelength_mm=20.0, sigma_mm=0.001), sites, dz,
                          xy.mean(axis=0))
    assert learned.at_bound[1] == "lower" and learned.prior.amplitude_mm < 0.003
    assert not learned.misfit, learned.loo.reasons


def test_loo_flags_a_spike_and_passes_the_clean_field():
    sites, center, dz = draw(TRUTH, 40, 8)
    clean = loo_check(TRUTH, sites, dz, center)
    assert not clean.misfit and 0.4 < clean.statistic < 2.0
    spiked = dz.copy()
    spiked[5] += 0.08
    check = loo_check(TRUTH, sites, spiked, center)
    assert check.misfit and int(np.argmax(np.abs(check.z))) == 5


def test_too_few_touches_is_refused():
    sites, center, dz = draw(TRUTH, 5, 1)
    with pytest.raises(LearningError):
        learn_prior(USER, sites, dz, center)


def test_two_touches_of_one_spot_that_disagree_are_both_screened():
    from app.reconstruction.field_learning import repeat_outliers

    sites = Sites(np.array([[0.0, 0.0], [0.1, 0.0], [5.0, 0.0], [5.1, 0.0], [5.2, 0.0], [9.0, 0.0]]), np.zeros((6, 2)))
    dz = np.array([0.0, 0.2, 0.01, 0.011, 0.3, 0.05])       # spot 1: 2 disagree; spot 2: the third is off the median
    assert repeat_outliers(sites, dz, 0.001).tolist() == [0, 1, 4]
    assert repeat_outliers(sites, dz[[0, 2, 5, 1, 3, 4]] * 0.0, 0.001).tolist() == []


def test_a_likelihood_with_its_kept_kernels_gives_what_a_fresh_one_gives():
    """The kernels kept for the last wavelengths asked give, bit for bit, the value and the
    gradient a fresh likelihood computes, in an order that hits and misses them (value alone
    first, then with the gradient, wavelengths coming back)."""
    sites, center, dz = draw(TRUTH, 40, 3)
    warm = _Likelihood(USER, sites, dz, center)
    thetas = [np.log(t) for t in ([0.1, 12.0, 0.003], [0.11, 12.0, 0.003], [0.1, 9.0, 0.002], [0.1, 12.0, 0.004],
                                  [0.2, 15.0, 0.001], [0.2, 9.0, 0.001], [0.1, 12.0, 0.003])]
    for theta in thetas:
        value = warm.value(theta)
        got, grad = warm(theta)
        fresh = _Likelihood(USER, sites, dz, center)
        want, want_grad = fresh(theta)
        assert value == fresh.value(theta) and got == want and np.array_equal(grad, want_grad)
