"""The deviation prior learned from the touches, and the model's fit checked.

The field planner designs stations for a prior the user states (peak amplitude, shortest
wavelength, probe noise, placement tolerances: :class:`app.probing.deviation_prior.DeviationPrior`);
a real part's error spectrum is not known in advance.  :func:`learn_prior` fits the prior's
hyperparameters to the measured deviations by **type-II maximum likelihood**: the log marginal
likelihood of a zero-mean Gaussian process with covariance

    K(theta) = rms^2 jinc(r; wavelength) + B diag(placement sd^2) B' + sigma^2 I

    log p(dz | theta) = -1/2 dz' K^-1 dz - 1/2 log det K - n/2 log 2 pi

is maximised over theta = (log rms, log wavelength, log sigma) with L-BFGS-B inside bounds around the user's
values (the placement sd's are kept at the user's tolerances: a handful of rigid terms is not identifiable from
a few dozen touches beside the field).  The likelihood is multimodal in the wavelength (a short-wavelength model
can explain any data as noise), so the search starts from a coarse grid of wavelengths and refines the best.

``method="reml"`` maximises the restricted likelihood instead: the offset and the two tilts are fixed effects
with a flat prior, integrated out (the likelihood of the touches' contrasts those terms cannot change), the
other placement terms kept at their tolerances (:class:`_Likelihood`).  ML treats the offset and tilts as known
to their tolerances; REML does not lean on those tolerances.  The bench ``tests/bench/test_bench_learning.py``
measures both.

Gross outliers (a chip or dust under the stylus, a bounced touch) would be explained by a short wavelength or a
large noise: one 0.3 mm spike can halve the learned wavelength.  So before the fit, :func:`screen_outliers`
takes out the touches their own re-touches contradict (a spot touched again reads the part where the first touch
read the chip), then those whose standardised leave-one-out residual is more than SCREEN_K robust sd (1.4826 x
the median |z|, at least 1) of all of them and more than SCREEN_FLOOR_MM, the least consistent first, under the
user's prior; the prior is learned from the rest, and the screen is run again under the learned prior (a touch
the first screen missed or wrongly took out is judged again).  The screened touches are reported (``screened``);
the fit and its outlier rejection still see every touch.

Uncertainty: the inverse of the Hessian of -log p in the log parameters at the optimum (the Laplace
approximation; central differences, :func:`app.reconstruction.laplace.laplace_covariance`), reported as the sd
of each log parameter (a relative sd) — a parameter at its bound says so instead — and the correlation of the
log amplitude and log wavelength (:mod:`app.reconstruction.hyper_bound`).

Fit check: the exact leave-one-out residuals of the fitted GP, r_i = (K^-1 dz)_i / (K^-1)_ii with sd_i =
(K^-1)_ii^-1/2, standardised z_i = r_i / sd_i (N(0, 1) each if the model holds). The misfit statistic is
``mean(z^2)`` (1 for a model that holds); the model **misfits** when the largest |z| exceeds the two-sided
Bonferroni quantile at ``MISFIT_ALPHA`` over the n touches, when ``mean(z^2)`` exceeds its chi-square quantile
at the same level, or when the fitted wavelength sits on its lower bound (the field is shorter than the shortest
wavelength allowed), or when the learned noise exceeds NOISE_MISFIT x the user's (the probe's repeatability):
what the stations cannot resolve shows up as noise.  A field on the wavelength's lower bound is a misfit only
when it is likelier than noise: the likelihood ratio against the same model with the field at its smallest
amplitude and the noise refitted passes its level-``MISFIT_ALPHA`` quantile (the 50:50 mixture of chi-square 0
and 1 of a variance on its bound).  Below that the short field stands for no more than noise (a part with no
field beyond the rigid terms, touches a little noisier than the stated repeatability: the readout's rounding),
the wavelength is not determined, and the touches are judged by the noise rule with the refitted noise.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.linalg.lapack import dpotri
from scipy.optimize import minimize, minimize_scalar
from scipy.special import chdtri, ndtri

from app.domain.errors import InvalidInput
from app.geometry.tolerance import COVARIANCE_JITTER_REL
from app.probing import bessel_table
from app.probing.deviation_prior import DeviationPrior, Sites, placement_basis
from app.reconstruction.laplace import correlation, covariance_sd, laplace_covariance

AMPLITUDE_RANGE = 20.0      # the learned amplitude within [user / 20, user x 20]
WAVELENGTH_FLOOR_MM = 3.0   # the shortest wavelength the learning may find (a probe ball's scale)
WAVELENGTH_RANGE = 4.0      # longest: user x 4
# the learned probe noise within [user x 1, user x 50]: never below the probe's repeatability
NOISE_RANGE = (1.0, 50.0)
GRID_WAVELENGTHS = 10       # start points of the search (log-spaced over the wavelength bounds)
MISFIT_ALPHA = 0.01         # false-alarm level of the misfit test
HESSIAN_STEP = 1e-3         # central-difference step in the log parameters
KERNELS_KEPT = 2            # a likelihood keeps the kernels of its last this many wavelengths
MIN_TOUCHES = 8
NOISE_MISFIT = 5.0          # learned noise over the user's (the probe's repeatability) that is a misfit
NAMES = ("amplitude_mm", "wavelength_mm", "sigma_mm")
SCREEN_K = 6.0              # a touch this many robust sd off what the others predict is screened out
SCREEN_FLOOR_MM = 0.03      # ... and this far (mm): no smooth part's touch is screened for noise
SCREEN_SHARE = 0.1          # at most this share of the touches is screened out
REPEAT_RADIUS_MM = 0.5      # touches this close read the same spot (a re-touch)
FIXED_TERMS = (0, 4, 5)     # placement_basis columns REML integrates out: the offset and the two tilts
METHODS = ("ml", "reml")
DEFAULT_METHOD = "ml"


class LearningError(InvalidInput):
    """Too few or bad touches to learn a prior from."""


@dataclass(frozen=True)
class Bounds:
    """Search bounds (lo, hi) of amplitude (peak), wavelength and noise, mm."""

    amplitude_mm: tuple[float, float]
    wavelength_mm: tuple[float, float]
    sigma_mm: tuple[float, float]


def default_bounds(prior: DeviationPrior, shortest_wavelength_mm: float | None = None) -> Bounds:
    """Bounds around the user's prior; ``shortest_wavelength_mm`` (default
    max(WAVELENGTH_FLOOR_MM, wavelength / 4)) is the shortest wavelength allowed."""
    shortest = shortest_wavelength_mm or max(WAVELENGTH_FLOOR_MM, prior.wavelength_mm / 4)
    sigma = max(prior.sigma_mm, 1e-5)
    return Bounds((prior.amplitude_mm / AMPLITUDE_RANGE, prior.amplitude_mm * AMPLITUDE_RANGE),
                  (shortest, max(prior.wavelength_mm * WAVELENGTH_RANGE, shortest * 1.01)),
                  (sigma * NOISE_RANGE[0], sigma * NOISE_RANGE[1]))


@dataclass(frozen=True)
class LooCheck:
    """Standardised leave-one-out residuals of a fitted field and the misfit verdict.

    residual_mm (n,), sd_mm (n,), z (n,) = residual / sd; statistic = mean(z^2);
    z_limit: the Bonferroni |z| limit; statistic_limit: mean(z^2)'s limit; misfit: bool;
    reasons: why (empty when the model holds)."""

    residual_mm: np.ndarray
    sd_mm: np.ndarray
    z: np.ndarray
    statistic: float
    z_limit: float
    statistic_limit: float
    misfit: bool
    reasons: tuple[str, ...]


@dataclass(frozen=True)
class LearnedPrior:
    """The prior fitted to the touches.

    prior: the user's prior with amplitude, wavelength and noise replaced by the ML values;
    start: the user's prior; bounds; log_sd (3,): sd of (log amplitude, log wavelength,
    log sigma) from the Hessian (NaN where a parameter sits on a bound); at_bound (3,) str:
    "lower" / "upper" / ""; log_likelihood (at the optimum) and start_log_likelihood (the
    user's prior); loo: the fit check under the learned prior; n: touches used; screened: the
    touches screened out; method: "ml" or "reml" (the likelihood maximised);
    log_correlation: the correlation of the log amplitude and log wavelength estimates (the
    same Hessian's; NaN where either sits on a bound)."""

    prior: DeviationPrior
    start: DeviationPrior
    bounds: Bounds
    log_sd: np.ndarray
    at_bound: tuple[str, str, str]
    log_likelihood: float
    start_log_likelihood: float
    loo: LooCheck
    n: int
    screened: tuple[int, ...] = ()
    method: str = DEFAULT_METHOD
    log_correlation: float = math.nan

    @property
    def misfit(self) -> bool:
        return self.loo.misfit

    def as_dict(self) -> dict[str, Any]:
        """JSON form: each parameter's value, the user's value, its relative sd and bound; the log correlation."""
        values = (self.prior.amplitude_mm, self.prior.wavelength_mm, self.prior.sigma_mm)
        starts = (self.start.amplitude_mm, self.start.wavelength_mm, self.start.sigma_mm)
        out: dict[str, Any] = {
            name: {"value": float(v), "prior": float(s),
                   "relative_sd": None if not math.isfinite(sd) else float(math.expm1(sd)),
                   "at_bound": b or None}
            for name, v, s, sd, b in zip(NAMES, values, starts, self.log_sd, self.at_bound)}
        rho = self.log_correlation
        out |= {"amplitude_wavelength_correlation": float(rho) if math.isfinite(rho) else None, "touches": self.n,
                "screened": list(self.screened), "method": self.method, "log_likelihood": self.log_likelihood,
                "prior_log_likelihood": self.start_log_likelihood,
                "loo": {"statistic": self.loo.statistic, "statistic_limit": self.loo.statistic_limit,
                        "max_abs_z": float(np.abs(self.loo.z).max()), "z_limit": self.loo.z_limit,
                        "misfit": self.loo.misfit, "reasons": list(self.loo.reasons)}}
        return out


class _Likelihood:
    """-log p(dz | theta) and its gradient over theta = (log amplitude, log wavelength,
    log sigma), with the distances and the placement part computed once.  The kernel is
    symmetric (r_ij = r_ji exactly): its Bessel functions are evaluated on the upper triangle
    (i <= j) and mirrored.

    ``method`` "reml": the restricted likelihood instead, the offset and the tilts
    (FIXED_TERMS, the (n, 3) basis H) fixed effects with a flat prior, integrated out:

        -log p_R = 1/2 dz' P dz + 1/2 log det K + 1/2 log det H'K^-1 H + (n - 3)/2 log 2 pi,
        P = K^-1 - K^-1 H (H'K^-1 H)^-1 H'K^-1,   d(-log p_R) = 1/2 tr((P - P dz dz' P) dK)

    with K = the field + the other placement terms (their tolerances) + the noise; "ml"
    is the same with P = K^-1 and no H term.  ML estimates the amplitude and the wavelength
    as if the offset and tilts were known; REML accounts for their being estimated."""

    def __init__(self, prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray,
                 method: str = "ml") -> None:
        if method not in METHODS:
            raise LearningError(f"unknown learning method {method!r} (one of {', '.join(METHODS)})",
                                field="method", value=method)
        xy = sites.xy
        self.n = len(xy)
        upper = np.triu_indices(self.n)  # (i, j) i <= j, row-major; flat in a C-order (n, n): (i, j), (j, i)
        self.flat = (upper[0] * self.n + upper[1], upper[1] * self.n + upper[0])   # ~4x faster than index pairs
        self._kernels: dict[float, tuple[np.ndarray, np.ndarray | None]] = {}   # log wavelength -> kernel
        self.r_upper = np.hypot(xy[upper[0], 0] - xy[upper[1], 0], xy[upper[0], 1] - xy[upper[1], 1])
        self.diagonal = upper[0] == upper[1]                         # (n (n + 1) / 2,) bool
        self.pair_weight = np.where(self.diagonal, 1.0, 2.0)         # an off-diagonal pair counts twice
        basis = placement_basis(sites, center) * prior.basis_sd
        self.fixed: np.ndarray | None = None
        if method == "reml":
            random = [i for i in range(basis.shape[1]) if i not in FIXED_TERMS]
            self.fixed = placement_basis(sites, center)[:, list(FIXED_TERMS)]
            basis = basis[:, random]
        self.placement = basis @ basis.T
        self.peak = prior.peak_factor
        self.dz = dz

    def _symmetric(self, upper: np.ndarray) -> np.ndarray:
        """The (n, n) symmetric matrix whose upper triangle (row-major, i <= j) is ``upper``."""
        out = np.empty((self.n, self.n))
        flat = out.ravel()   # a view: out is C-contiguous
        flat[self.flat[0]] = upper
        flat[self.flat[1]] = upper
        return out

    def _kernel_upper(self, theta: np.ndarray, gradient: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """(jinc, d jinc / d log wavelength (None without ``gradient``)) on the upper triangle
        (n (n + 1) / 2,) at theta.  d jinc / d log wavelength = x jinc'(x) = 2 J2(x), and
        J2(x) = 2 J1(x) / x - J0(x) = jinc(x) - J0(x) (the Bessel recurrence): one J0 beside
        the J1 jinc needs, not a general-order J2 (~20x the cost of J0); both from their tables
        (:mod:`app.probing.bessel_table`, absolute error ~1e-14).  The last KERNELS_KEPT wavelengths'
        are kept (the Laplace sd's differences step the other parameters at one wavelength): read-only."""
        kept = self._kernels.get(float(theta[1]))
        if kept is not None and (kept[1] is not None or not gradient):
            return kept[0], kept[1] if gradient else None
        x = self.r_upper * (2.0 * math.pi / math.exp(theta[1]))
        jinc = bessel_table.jinc(x)
        djinc = 2.0 * (jinc - bessel_table.bessel_j0(x)) if gradient else None
        for a in (jinc, djinc):
            if a is not None:
                a.setflags(write=False)
        self._kernels.pop(float(theta[1]), None)
        self._kernels[float(theta[1])] = (jinc, djinc)
        while len(self._kernels) > KERNELS_KEPT:
            del self._kernels[next(iter(self._kernels))]
        return jinc, djinc

    def _covariance(self, theta: np.ndarray, jinc: np.ndarray) -> tuple[np.ndarray, float, float]:
        """(K (n, n) mm^2, rms^2, noise variance) at theta from the upper-triangle ``jinc``."""
        rms2 = (math.exp(theta[0]) / self.peak) ** 2
        noise = max(math.exp(2 * theta[2]), COVARIANCE_JITTER_REL * rms2)
        k = rms2 * self._symmetric(jinc) + self.placement
        k[np.diag_indices_from(k)] += noise
        return k, rms2, noise

    def parts(self, theta: np.ndarray, gradient: bool = True
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float, float]:
        """(K, jinc, d jinc / d log wavelength (None without ``gradient``), rms^2, noise
        variance) at theta, each matrix (n, n)."""
        jinc, djinc = self._kernel_upper(theta, gradient)
        k, rms2, noise = self._covariance(theta, jinc)
        return k, self._symmetric(jinc), None if djinc is None else self._symmetric(djinc), rms2, noise

    def __call__(self, theta: np.ndarray) -> tuple[float, np.ndarray]:
        """(-log p, its gradient (3,)) at theta.  The gradient's 1/2 tr(W dK) with W = K^-1 -
        alpha alpha' (REML: P - alpha alpha') is summed over the upper triangle (dK is
        symmetric: each off-diagonal pair counted twice), K^-1 by LAPACK's potri from the
        Cholesky factor (a third of the flops of solving for the identity)."""
        jinc, djinc = self._kernel_upper(theta, True)
        assert djinc is not None
        k, rms2, noise = self._covariance(theta, jinc)
        try:
            factor = cho_factor(k, lower=True)
        except np.linalg.LinAlgError:
            return 1e30, np.zeros(3)
        if self.fixed is None:
            alpha = cho_solve(factor, self.dz)
            value = self._value(factor, alpha)
            kinv, info = dpotri(factor[0], lower=1)   # K^-1 in the lower triangle
            if info:
                return 1e30, np.zeros(3)
            w = np.take(kinv.T, self.flat[0])         # (K^-1)_ji, i <= j: the lower triangle
        else:
            p = cho_solve(factor, np.eye(len(k)))   # K^-1, then P
            kh = p @ self.fixed
            try:
                inner = cho_factor(self.fixed.T @ kh, lower=True)
            except np.linalg.LinAlgError:
                return 1e30, np.zeros(3)
            p = p - kh @ cho_solve(inner, kh.T)
            alpha = p @ self.dz
            value = self._restricted_value(factor, inner, alpha)
            w = np.take(p, self.flat[0])
        w = w - np.take(np.outer(alpha, alpha), self.flat[0])   # W's upper triangle
        trace_w = float(np.sum(w[self.diagonal]))
        w *= self.pair_weight
        grad = 0.5 * np.array([2 * rms2 * float(w @ jinc), rms2 * float(w @ djinc), trace_w * 2 * noise])
        return value, grad

    def _value(self, factor: tuple[np.ndarray, bool], alpha: np.ndarray) -> float:
        return float(0.5 * self.dz @ alpha + np.sum(np.log(np.diag(factor[0])))
                     + 0.5 * len(self.dz) * math.log(2 * math.pi))

    def _restricted_value(self, factor: tuple[np.ndarray, bool], inner: tuple[np.ndarray, bool],
                          alpha: np.ndarray) -> float:
        """-log p_R from K's factor, H'K^-1 H's factor and alpha = P dz (n,)."""
        assert self.fixed is not None
        dof = len(self.dz) - self.fixed.shape[1]
        return float(0.5 * self.dz @ alpha + np.sum(np.log(np.diag(factor[0])))
                     + np.sum(np.log(np.diag(inner[0]))) + 0.5 * dof * math.log(2 * math.pi))

    def value(self, theta: np.ndarray) -> float:
        """-log p(dz | theta) alone (the same number :meth:`__call__` gives, without the gradient)."""
        k = self.covariance(theta)
        try:
            factor = cho_factor(k, lower=True)
        except np.linalg.LinAlgError:
            return 1e30
        kinv_dz = cho_solve(factor, self.dz)
        if self.fixed is None:
            return self._value(factor, kinv_dz)
        kinv_h = cho_solve(factor, self.fixed)   # (n, 3)
        try:
            inner = cho_factor(self.fixed.T @ kinv_h, lower=True)
        except np.linalg.LinAlgError:
            return 1e30
        alpha = kinv_dz - kinv_h @ cho_solve(inner, self.fixed.T @ kinv_dz)   # P dz
        return self._restricted_value(factor, inner, alpha)

    def covariance(self, theta: np.ndarray) -> np.ndarray:
        """K (n, n) mm^2 at theta."""
        return self._covariance(theta, self._kernel_upper(theta, False)[0])[0]


def _theta(prior: DeviationPrior) -> np.ndarray:
    return np.log([prior.amplitude_mm, prior.wavelength_mm, max(prior.sigma_mm, 1e-9)])


def log_marginal_likelihood(prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray,
                            method: str = "ml") -> float:
    """log p(dz (n,) | prior) mm-based, of the touches at ``sites`` (n,) (``method`` "reml":
    the restricted likelihood, see :class:`_Likelihood`)."""
    return -_Likelihood(prior, sites, np.asarray(dz, dtype=float), center, method).value(_theta(prior))


def touch_precision(prior: DeviationPrior, sites: Sites, center: np.ndarray) -> np.ndarray:
    """K^-1 (n, n) 1/mm^2 of the touches at ``sites`` (n,) under ``prior`` (field, placement terms, noise)."""
    return np.linalg.inv(_Likelihood(prior, sites, np.zeros(len(sites.xy)), center).covariance(_theta(prior)))


def loo_check(prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray,
              alpha: float = MISFIT_ALPHA) -> LooCheck:
    """Standardised LOO residuals of the GP ``prior`` on the touches and the misfit test."""
    q = touch_precision(prior, sites, center)
    d = np.diag(q)
    resid = (q @ dz) / d
    sd = 1.0 / np.sqrt(d)
    z = resid / sd
    n = len(dz)
    z_limit = -float(ndtri(alpha / (2 * n)))  # the normal's upper quantile
    statistic = float(np.mean(z ** 2))
    statistic_limit = float(chdtri(n, alpha) / n)  # chi-square(n)'s upper quantile
    reasons = []
    if np.abs(z).max() > z_limit:
        i = int(np.argmax(np.abs(z)))
        reasons.append(f"touch {i} is {abs(z[i]):.1f} sd from what the others predict (limit {z_limit:.1f})")
    if statistic > statistic_limit:
        reasons.append(f"mean squared standardised residual {statistic:.2f} (limit {statistic_limit:.2f})")
    return LooCheck(resid, sd, z, statistic, z_limit, statistic_limit, bool(reasons), tuple(reasons))


def repeat_outliers(sites: Sites, dz: np.ndarray, sigma_mm: float) -> np.ndarray:
    """Indices (k,) of touches their own re-touches contradict: touches within REPEAT_RADIUS_MM
    of each other read the same spot; one more than max(SCREEN_K x sigma, SCREEN_FLOOR_MM)
    off the spot's median is out (two that disagree so: both, which one is right cannot be
    told).  A chip or dust reads once; the spot's other touches read the part."""
    xy = sites.xy
    near = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1]) <= REPEAT_RADIUS_MM
    limit = max(SCREEN_K * sigma_mm, SCREEN_FLOOR_MM)
    out: set[int] = set()
    for i in range(len(dz)):
        spot = np.flatnonzero(near[i])
        if len(spot) < 2:
            continue
        off = np.abs(dz[spot] - np.median(dz[spot])) > limit
        if len(spot) == 2 and abs(dz[spot[0]] - dz[spot[1]]) > limit:
            off[:] = True
        out.update(int(j) for j in spot[off])
    return np.array(sorted(out), dtype=int)


def screen_outliers(prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Indices (k,) of the touches that are gross outliers under ``prior``: those their own
    re-touches contradict (:func:`repeat_outliers`), then those whose standardised
    leave-one-out residual over SCREEN_K robust sd of all of them (1.4826 x median |z|, at
    least 1: a prior that misjudges the field scales every z alike) and residual over
    SCREEN_FLOOR_MM; the least consistent is taken out and the rest judged again, at most
    SCREEN_SHARE of the touches."""
    keep = np.ones(len(dz), dtype=bool)
    keep[repeat_outliers(sites, dz, prior.sigma_mm)] = False
    while (~keep).sum() < SCREEN_SHARE * len(dz):
        idx = np.flatnonzero(keep)
        check = loo_check(prior, sites.take(idx), dz[idx], center)
        scale = max(1.0, 1.4826 * float(np.median(np.abs(check.z))))
        bad = (np.abs(check.z) > SCREEN_K * scale) & (np.abs(check.residual_mm) > SCREEN_FLOOR_MM)
        if not bad.any():
            break
        keep[idx[int(np.argmax(np.where(bad, np.abs(check.z), -1.0)))]] = False
    return np.flatnonzero(~keep)


def learn_prior(prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray,
                bounds: Bounds | None = None, screen: bool = True, method: str = DEFAULT_METHOD) -> LearnedPrior:
    """Type-II ML fit of amplitude, wavelength and noise to deviations dz (n,) mm measured at
    ``sites`` (n,), placement centre ``center`` (2,), gross outliers screened out first
    (:func:`screen_outliers` under the user's prior, then again under the learned one).
    ``method``: "ml" the marginal likelihood, "reml" the restricted one (:class:`_Likelihood`).
    Raises LearningError below MIN_TOUCHES touches or for non-finite values."""
    dz = np.asarray(dz, dtype=float)
    n = len(dz)
    if n < MIN_TOUCHES:
        raise LearningError(f"learning the prior needs at least {MIN_TOUCHES} touches, got {n}",
                            field="stations", value=n)
    if not np.isfinite(dz).all():
        raise LearningError("a measured deviation is not finite", field="dz", value=None)
    if not screen:
        return _learn(prior, sites, dz, center, bounds, method)
    out = np.zeros(0, dtype=int)
    learned = None
    for _ in range(2):  # under the user's prior, then under the learned one
        now = screen_outliers(prior if learned is None else learned.prior, sites, dz, center)
        if learned is not None and np.array_equal(now, out):
            break
        out = now
        kept = np.setdiff1d(np.arange(n), out)
        learned = _learn(prior, sites.take(kept), dz[kept], center, bounds, method)
    assert learned is not None
    return replace(learned, n=n, screened=tuple(int(i) for i in out))


def _learn(prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray,
           bounds: Bounds | None, method: str) -> LearnedPrior:
    """:func:`learn_prior` on the touches given, none screened out."""
    n = len(dz)
    bounds = bounds or default_bounds(prior)
    lo = np.log([bounds.amplitude_mm[0], bounds.wavelength_mm[0], bounds.sigma_mm[0]])
    hi = np.log([bounds.amplitude_mm[1], bounds.wavelength_mm[1], bounds.sigma_mm[1]])
    likelihood = _Likelihood(prior, sites, dz, center, method)
    objective = likelihood.value
    start = np.clip(_theta(prior), lo, hi)
    starts = [start]
    for log_w in np.linspace(lo[1], hi[1], GRID_WAVELENGTHS):
        amp = math.log(max(float(np.std(dz)) * prior.peak_factor, math.exp(lo[0])))
        starts.append(np.clip(np.array([amp, log_w, start[2]]), lo, hi))
    scored = sorted(starts, key=objective)
    best = None
    for theta0 in scored[:2]:
        res = minimize(likelihood, theta0, jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi)))
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    theta = np.asarray(best.x, dtype=float)
    span = hi - lo
    at = tuple("lower" if t - a < 1e-3 * s else "upper" if b - t < 1e-3 * s else ""
               for t, a, b, s in zip(theta, lo, hi, span))
    log_cov = laplace_covariance(objective, theta, at, HESSIAN_STEP)
    log_sd = covariance_sd(log_cov)
    learned = replace(prior, amplitude_mm=float(math.exp(theta[0])), wavelength_mm=float(math.exp(theta[1])),
                      sigma_mm=float(math.exp(theta[2])))
    loo = loo_check(learned, sites, dz, center)
    scatter = learned.sigma_mm
    if at[1] == "lower":
        as_noise = _as_noise(likelihood, theta, lo, hi)
        if 2.0 * (as_noise[0] - float(best.fun)) > chdtri(1, 2 * MISFIT_ALPHA):
            loo = replace(loo, misfit=True, reasons=loo.reasons + (
                f"the field's wavelength is at the shortest allowed ({bounds.wavelength_mm[0]:.1f} mm) "
                "or shorter",))
        else:  # a field no likelier than noise: the touches are judged as the noise it stands for
            scatter = max(scatter, as_noise[1])
    if scatter > NOISE_MISFIT * prior.sigma_mm:
        loo = replace(loo, misfit=True, reasons=loo.reasons + (
            f"the touches scatter {scatter * 1000:.1f} um about the field, {scatter / prior.sigma_mm:.0f}x "
            "the probe's repeatability: structure shorter than the stations resolve, or misreading touches",))
    return LearnedPrior(learned, prior, bounds, log_sd, (at[0], at[1], at[2]), -float(best.fun),
                        -objective(start), loo, n, method=method, log_correlation=correlation(log_cov, 0, 1))


def _as_noise(likelihood: _Likelihood, theta: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[float, float]:
    """The touches read as noise instead of a field at ``theta``'s wavelength: the field at its
    smallest amplitude allowed, the noise refitted; (-log p at that optimum, the noise sd mm)."""
    def value(log_sigma: float) -> float:
        return likelihood.value(np.array([lo[0], theta[1], log_sigma]))

    res = minimize_scalar(value, bounds=(lo[2], hi[2]), method="bounded")
    return float(res.fun), float(math.exp(res.x))
