"""The run's bound forecast for stations not touched yet, and a round sized by it.

The run's bound (:func:`app.reconstruction.field_trust.run_bounds`) depends on where the
stations are and on the learned prior taken HYPER_SD of its own sd on the unfavourable side
(:func:`app.reconstruction.field_trust.cautious_prior`), not on what the stations read.  So
the bound a round's stations will give can be computed before they are touched, under the
prior learned so far (:func:`forecast_run_bound`).  Two parts of it change as stations are
added: the posterior sd between them (computed exactly for the planned stations) and the
hyperparameters' own sd (fewer touches, less known).  The latter is forecast from the
**expected Fisher information** of the log parameters at the planned design,

    F_ab = 1/2 tr(K^-1 dK/dtheta_a K^-1 dK/dtheta_b),   theta = (log A, log lambda, log sigma)

(the Laplace sd the learning reports is the observed-information counterpart): the learned
relative sd scaled by sqrt((F_after^-1)_aa / (F_now^-1)_aa) (:func:`forecast_learned`), a
parameter on its bound kept out of F as the learning keeps it out of its Hessian.

:func:`plan_for_bound` sizes a round by the forecast: the loosest pointwise target (fewest
stations) whose planned stations' forecast bound is within the aim, searched by bisection in
log target.  The forecast only sizes the round: the rounds still end on the bound of the
stations actually touched, learned again from what they read
(:mod:`app.reconstruction.field_sequential`), and the verification points decide the verdict.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from app.probing.deviation_prior import DeviationPrior, Sites, fit_posterior
from app.probing.field import FieldPlan
from app.reconstruction.field_learning import NAMES, LearnedPrior, _Likelihood
from app.reconstruction.field_trust import cautious_prior, posterior_trace_bound

SEARCH_FLOOR = 0.2   # a round's pointwise target is searched down to this fraction of its own
SEARCH_STEPS = 6     # bisection steps in log target (the first at the proportional guess)


def expected_log_sd(prior: DeviationPrior, sites: Sites, center: np.ndarray,
                    free: Sequence[bool] = (True, True, True)) -> np.ndarray:
    """The sd (3,) of (log amplitude, log wavelength, log sigma) from the expected Fisher
    information of touches at ``sites`` (n,) under ``prior``; only the ``free`` (3,)
    parameters are estimated (the others fixed, NaN).  Needs no measured values."""
    out = np.full(3, np.nan)
    idx = [i for i in range(3) if free[i]]
    if not idx:
        return out
    like = _Likelihood(prior, sites, np.zeros(len(sites.xy)), center)
    theta = np.log([prior.amplitude_mm, prior.wavelength_mm, max(prior.sigma_mm, 1e-9)])
    k, jinc, djinc, rms2, noise = like.parts(theta)
    assert djinc is not None
    try:
        kinv = cho_solve(cho_factor(k, lower=True), np.eye(len(k)))
    except np.linalg.LinAlgError:
        return out
    parts = [kinv @ (2.0 * rms2 * jinc), kinv @ (rms2 * djinc), kinv * (2.0 * noise)]
    fisher = np.array([[0.5 * float(np.sum(parts[a] * parts[b].T)) for b in idx] for a in idx])
    try:
        cov = np.linalg.inv(fisher)
    except np.linalg.LinAlgError:
        return out
    out[idx] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return out


def forecast_learned(learned: LearnedPrior, sites_now: Sites, sites_after: Sites,
                     center: np.ndarray) -> dict[str, Any]:
    """``learned``'s JSON form (:meth:`LearnedPrior.as_dict`) with the amplitude's and the
    wavelength's relative sd forecast for the touches at ``sites_after`` (m,) instead of
    ``sites_now`` (n,): each log sd scaled by the ratio of their expected-information sd
    (:func:`expected_log_sd`).  A parameter on a bound or without an sd is kept as it is."""
    out = learned.as_dict()
    free = [not b for b in learned.at_bound]
    now = expected_log_sd(learned.prior, sites_now, center, free)
    after = expected_log_sd(learned.prior, sites_after, center, free)
    for i, name in enumerate(NAMES[:2]):
        rel = out[name]["relative_sd"]
        if rel is None or not (now[i] > 0 and math.isfinite(after[i])):
            continue
        out[name] = dict(out[name], relative_sd=float(math.expm1(math.log1p(rel) * after[i] / now[i])))
    return out


def forecast_run_bound(learned: LearnedPrior, sites_now: Sites, sites_after: Sites, center: np.ndarray,
                       paths: Sequence[Any], coverage: float, sigma_mm: float | None = None) -> float:
    """The run's bound (mm) the stations ``sites_after`` (m,) will give, forecast under the
    prior ``learned`` from the touches at ``sites_now`` (n,): the largest trace bound of the
    posterior under :func:`cautious_prior` with the forecast sd (:func:`forecast_learned`),
    over the TracePolylines ``paths`` sharing the confidence (as
    :func:`app.reconstruction.field_trust.run_bounds`)."""
    prior = cautious_prior(learned.prior, forecast_learned(learned, sites_now, sites_after, center))
    if sigma_mm is not None:
        prior = replace(prior, sigma_mm=sigma_mm)
    posterior = fit_posterior(prior, sites_after, np.zeros(len(sites_after.xy)), center)
    return max(posterior_trace_bound(posterior, p, coverage, len(paths)) for p in paths)


def plan_for_bound(plan: Callable[[float], FieldPlan], forecast: Callable[[FieldPlan], float],
                   guess_mm: float, plan_target_mm: float, aim_mm: float,
                   floor: float = SEARCH_FLOOR) -> tuple[FieldPlan, float]:
    """(the stations ``plan(pointwise target mm)`` adds, the target) for the loosest target in
    [``floor`` x ``plan_target_mm``, ``plan_target_mm``) whose stations' forecast run's
    bound ``forecast(plan)`` (mm) is within ``aim_mm``: bisection in log target from
    ``guess_mm``, SEARCH_STEPS plans (the target is taken to be monotone in the stations it
    buys).  None within the aim: the tightest target's plan (the next round learns from it
    and goes on)."""
    lo, hi = math.log(plan_target_mm * floor), math.log(plan_target_mm)
    t = min(max(math.log(guess_mm), lo), hi)
    best: tuple[FieldPlan, float] | None = None
    for _ in range(SEARCH_STEPS):
        more = plan(math.exp(t))
        if more.count and forecast(more) <= aim_mm:
            best, lo = (more, math.exp(t)), t
        else:
            hi = t
        t = 0.5 * (lo + hi)
    if best is not None:
        return best
    return plan(plan_target_mm * floor), plan_target_mm * floor
