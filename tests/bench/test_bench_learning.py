"""Bench: how well the deviation prior's hyperparameters are learned from n touches.

Run: .venv/bin/python -m pytest tests/bench/test_bench_learning.py -s -o addopts="" -q
(``LEARNING_DRAWS`` draws per case, default 10; ``LEARNING_COUNTS`` the touch counts, default
"30,60,120"; ``LEARNING_METHODS`` the likelihoods compared, default "ml,reml").

Fields drawn from a known prior (the truth: amplitude, wavelength and noise are defined),
touched at n = 30, 60 and 120 points scattered over 40 x 30 mm, a fifth of them touched again
0.2 mm away (the noise needs repeats), the user's prior at the defaults (A 0.2 mm, lambda
20 mm, 1 um noise) as start and bounds.  For each: the learned amplitude and wavelength over
the truth (within 20 %?), whether the truth lies within 2 stated sd (the Laplace sd of the
log parameters), and whether :func:`learn_prior` found the likelihood's global maximum
(L-BFGS-B from a 12 x 2 grid of wavelengths and amplitudes, the best kept): a miss is a local
optimum, not the data.  Each case is learned by both likelihoods: the marginal one (ML) and
the restricted one (REML: the offset and the tilts integrated out), each against its own
global maximum.  Beside them, the sd of the log amplitude and log wavelength the expected
(Fisher) information of the same touches allows under the truth
(:func:`app.reconstruction.field_forecast.expected_log_sd`, the Cramer-Rao bound of an unbiased
estimate) and the share of draws within 20 % it implies (2 Phi(log 1.2 / sd) - 1, averaged):
what no estimator can do much better than from these touches.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.stats import norm

from app.probing.deviation_prior import DeviationPrior, Sites
from app.reconstruction.field_forecast import expected_log_sd
from app.reconstruction.field_learning import _Likelihood, default_bounds, learn_prior
from tests.helpers.field_draws import draw

DRAWS = int(os.environ.get("LEARNING_DRAWS", "10"))
USER = DeviationPrior()
TRUTHS = (DeviationPrior(amplitude_mm=0.2, wavelength_mm=6.0, sigma_mm=0.002),
          DeviationPrior(amplitude_mm=0.12, wavelength_mm=10.0, sigma_mm=0.002),
          DeviationPrior(amplitude_mm=0.06, wavelength_mm=15.0, sigma_mm=0.002))
COUNTS = tuple(int(n) for n in os.environ.get("LEARNING_COUNTS", "30,60,120").split(","))
METHODS = tuple(os.environ.get("LEARNING_METHODS", "ml,reml").split(","))


def global_optimum(sites: Sites, dz: np.ndarray, center: np.ndarray, method: str) -> tuple[float, np.ndarray]:
    """The largest log (``method``: marginal or restricted) likelihood found from a 12 x 2 grid
    of starts and its (amplitude, wavelength, noise) (3,) mm."""
    likelihood = _Likelihood(USER, sites, dz, center, method)
    b = default_bounds(USER)
    lo = np.log([b.amplitude_mm[0], b.wavelength_mm[0], b.sigma_mm[0]])
    hi = np.log([b.amplitude_mm[1], b.wavelength_mm[1], b.sigma_mm[1]])
    best, where = math.inf, np.zeros(3)
    for log_w in np.linspace(lo[1], hi[1], 12):
        for amplitude in (0.03, 0.3):
            start = np.clip([math.log(amplitude), log_w, lo[2] + 0.5], lo, hi)
            res = minimize(likelihood, start, jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi)))
            if res.fun < best:
                best, where = float(res.fun), np.exp(res.x)
    return -best, where


@pytest.mark.timeout(3600)
def test_hyperparameters_recovered_from_touches():
    print("\nmethod  n  lambda  A_true  within 20 % (A, lambda, both)  truth within 2 sd  global max found  "
          "A ratio (min-max)  lambda ratio (min-max)  median rel sd (A, lambda)")
    summary = {}
    for method, n, truth in ((m, n, t) for m in METHODS for n in COUNTS for t in TRUTHS):
        ra, rw, cover, found, sds, glob, crb = [], [], [], [], [], [], []
        for seed in range(DRAWS):
            sites, center, dz = draw(truth, n, 1000 * n + seed, pairs=n // 5)
            learned = learn_prior(USER, sites, dz, center, method=method)
            got = learned.prior
            ra.append(got.amplitude_mm / truth.amplitude_mm)
            rw.append(got.wavelength_mm / truth.wavelength_mm)
            err = np.abs(np.log([ra[-1], rw[-1]]))
            sd = learned.log_sd[:2]
            cover.append(bool(np.all(np.isfinite(sd)) and np.all(err <= 2 * sd)))
            sds.append(np.expm1(sd))
            best, where = global_optimum(sites, dz, center, method)
            found.append(learned.log_likelihood >= best - 1e-3)
            crb.append(expected_log_sd(truth, sites, center)[:2])
            glob.append(bool(np.all(np.abs(where[:2] / [truth.amplitude_mm, truth.wavelength_mm] - 1) < 0.2)))
        a_ok = np.abs(np.array(ra) - 1) < 0.2
        w_ok = np.abs(np.array(rw) - 1) < 0.2
        summary[(method, n, truth.wavelength_mm)] = int((a_ok & w_ok).sum())
        print(f"{method:5s} {n:4d} {truth.wavelength_mm:6.0f} {truth.amplitude_mm:7.2f}   {int(a_ok.sum()):3d} "
              f"{int(w_ok.sum()):3d} {int((a_ok & w_ok).sum()):3d} of {DRAWS}           {sum(cover):3d}            "
              f" {sum(found):3d}          {min(ra):.2f}-{max(ra):.2f}          {min(rw):.2f}-{max(rw):.2f}"
              f"            {np.nanmedian(np.array(sds)[:, 0]):.2f} {np.nanmedian(np.array(sds)[:, 1]):.2f}"
              f"   (the global maximum: both within 20 % in {sum(glob)}; information sd (A, lambda) "
              f"{np.median(np.array(crb)[:, 0]):.2f} {np.median(np.array(crb)[:, 1]):.2f}, log error rms "
              f"{np.sqrt(np.mean(np.log(ra) ** 2)):.2f} {np.sqrt(np.mean(np.log(rw) ** 2)):.2f}, within 20 % it "
              f"allows: {DRAWS * np.mean(2 * norm.cdf(np.log(1.2) / np.array(crb)[:, 0]) - 1):.1f} "
              f"{DRAWS * np.mean(2 * norm.cdf(np.log(1.2) / np.array(crb)[:, 1]) - 1):.1f})",
              flush=True)
    for method, n in ((m, n) for m in METHODS for n in COUNTS):
        both = sum(v for (m, k, _), v in summary.items() if (m, k) == (method, n))
        print(f"{method}, n = {n}: amplitude and wavelength both within 20 % in {both} of {DRAWS * len(TRUTHS)}")
    # the figures are the result; the one hard promise: more touches never learn worse overall
    for method in METHODS:
        assert sum(v for (m, k, _), v in summary.items() if (m, k) == (method, COUNTS[-1])) >= sum(
            v for (m, k, _), v in summary.items() if (m, k) == (method, COUNTS[0]))
