"""The run's bound forecast for stations not touched yet, and a round sized by it.

The run's bound (:func:`app.reconstruction.field_trust.run_bounds`) depends on where the
stations are and on the learned prior and its own uncertainty
(:func:`app.reconstruction.field_trust.cautious_bounds`), not on what the stations read.  So
the bound a round's stations will give can be computed before they are touched, under the
prior learned so far (:func:`forecast_run_bound`).  Two parts of it change as stations are
added: the posterior sd between them (computed exactly for the planned stations) and the
hyperparameters' own sd (fewer touches, less known).  The latter is forecast from the
**expected Fisher information** of the log parameters at the planned design,

    F_ab = 1/2 tr(K^-1 dK/dtheta_a K^-1 dK/dtheta_b),   theta = (log A, log lambda, log sigma)

(the Laplace sd the learning reports is the observed-information counterpart): the learned
relative sd scaled by sqrt((F_after^-1)_aa / (F_now^-1)_aa), at most sqrt((F_after^-1)_aa)
itself (:func:`forecast_learned`), a parameter on its bound kept out of F as the learning
keeps it out of its Hessian.

:func:`plan_for_bound` sizes a round by the forecast (the first round after the pilot, and
a round after a bound over the tolerance): the loosest pointwise target (fewest stations)
whose planned stations' forecast bound is within the aim, searched by bracketing in log
target, each step where the forecast's line in log-log through the bracket meets the aim.
The forecast only sizes the round: the rounds still end on the bound of the stations
actually touched, learned again from what they read (:mod:`app.reconstruction.field_sequential`),
and the verification points decide the verdict.

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
from app.reconstruction.field_trust import cautious_bounds, posterior_trace_bounds

SEARCH_FLOOR = 0.2   # a round's pointwise target is searched down to this fraction of its own
SEARCH_STEPS = 6     # steps in log target (the first at the proportional guess)
SEARCH_GUARD = 0.25  # a step lands at least this fraction of the bracket (log target) inside either end
SEARCH_WITHIN = 0.1  # the search ends once the loosest target within the aim is known to this fraction


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


def learned_free(learned: LearnedPrior) -> list[bool]:
    """The parameters (3,) the learning estimated: those not on a bound."""
    return [not b for b in learned.at_bound]


def forecast_learned(learned: LearnedPrior, sites_now: Sites, sites_after: Sites,
                     center: np.ndarray, now_log_sd: np.ndarray | None = None) -> dict[str, Any]:
    """``learned``'s JSON form (:meth:`LearnedPrior.as_dict`) with the amplitude's and the
    wavelength's relative sd forecast for the touches at ``sites_after`` (m,) instead of
    ``sites_now`` (n,): each log sd scaled by the ratio of their expected-information sd
    (:func:`expected_log_sd`), and no larger than the expected-information sd of
    ``sites_after`` itself (the Cramer-Rao forecast: the learning's Laplace sd from a few
    dozen touches scatters about it, and the rounds overshot on a pilot's large one; the
    rounds still end on the bound of the stations touched, learned again).  A parameter on a
    bound or without an sd is kept as it is.  ``now_log_sd`` (3,): ``expected_log_sd`` of
    ``sites_now`` when the caller has it (a round's search forecasts many designs from the
    same touches)."""
    out = learned.as_dict()
    free = learned_free(learned)
    now = expected_log_sd(learned.prior, sites_now, center, free) if now_log_sd is None else now_log_sd
    after = expected_log_sd(learned.prior, sites_after, center, free)
    for i, name in enumerate(NAMES[:2]):
        rel = out[name]["relative_sd"]
        if rel is None or not (now[i] > 0 and math.isfinite(after[i])):
            continue
        log_sd = min(math.log1p(rel) * after[i] / now[i], float(after[i]))
        out[name] = dict(out[name], relative_sd=float(math.expm1(log_sd)))
    return out


def forecast_run_bound(learned: LearnedPrior, sites_now: Sites, sites_after: Sites, center: np.ndarray,
                       paths: Sequence[Any], coverage: float, sigma_mm: float | None = None,
                       now_log_sd: np.ndarray | None = None) -> float:
    """The run's bound (mm) the stations ``sites_after`` (m,) will give, forecast under the
    prior ``learned`` from the touches at ``sites_now`` (n,): the largest trace bound over the
    TracePolylines ``paths`` sharing the confidence, allowing for the hyperparameters' forecast
    sd (:func:`forecast_learned`; the correlation the learning's) as
    :func:`app.reconstruction.field_trust.run_bounds` does (:func:`app.reconstruction.field_trust.cautious_bounds`).
    ``now_log_sd``: as :func:`forecast_learned`."""
    def bounds(prior: DeviationPrior) -> np.ndarray:
        if sigma_mm is not None:
            prior = replace(prior, sigma_mm=sigma_mm)
        posterior = fit_posterior(prior, sites_after, np.zeros(len(sites_after.xy)), center)
        return np.array(posterior_trace_bounds(posterior, paths, coverage))
    forecast = forecast_learned(learned, sites_now, sites_after, center, now_log_sd)
    return float(cautious_bounds(bounds, learned.prior, forecast).max())


def _next_target(lo: float, hi: float, at_lo: float | None, at_hi: float | None, aim: float,
                 extrapolate: bool) -> float:
    """The next log target in the bracket (``lo``, ``hi``) (log mm) whose ends' log forecasts
    are ``at_lo`` / ``at_hi`` (None: not forecast, a bound of the bracket or a plan adding
    nothing): where the line through them meets the log ``aim``, kept SEARCH_GUARD of the
    bracket inside either end (it shrinks by at least that much a step); with one end's
    forecast and ``extrapolate`` (once a search: a plan's count can stay put over a range of
    targets, its forecast with it), that line at slope 1 through it (the bound scales about
    as the pointwise target does); else, or that point outside the bracket, the middle."""
    if at_lo is not None and at_hi is not None and at_hi > at_lo:
        t = lo + (aim - at_lo) * (hi - lo) / (at_hi - at_lo)
        return min(max(t, lo + SEARCH_GUARD * (hi - lo)), hi - SEARCH_GUARD * (hi - lo))
    t = hi + aim - at_hi if at_hi is not None else lo + aim - at_lo if at_lo is not None else lo
    return t if extrapolate and lo < t < hi else 0.5 * (lo + hi)


def plan_for_bound(plan: Callable[[float], FieldPlan], forecast: Callable[[FieldPlan], float],
                   guess_mm: float, plan_target_mm: float, aim_mm: float,
                   floor: float = SEARCH_FLOOR, otherwise_mm: float | None = None) -> tuple[FieldPlan, float]:
    """(the stations ``plan(pointwise target mm)`` adds, the target) for the loosest target in
    [``floor`` x ``plan_target_mm``, ``plan_target_mm``) whose stations' forecast run's
    bound ``forecast(plan)`` (mm) is within ``aim_mm``: a bracket in log target narrowed from
    ``guess_mm``, each next target where the forecasts at its ends say the aim lies
    (:func:`_next_target`), at most SEARCH_STEPS plans (the target is taken to be monotone in the
    stations it buys), ended early once a target within the aim is known within SEARCH_WITHIN
    of the loosest (the bracket that narrow) or its plan has at most one station more than a
    looser target's that misses the aim (stations come whole: none lies between).  None within
    the aim: the plan for ``otherwise_mm``, by default the tightest target (the next round
    learns from it and goes on)."""
    lo, hi = math.log(plan_target_mm * floor), math.log(plan_target_mm)
    t = min(max(math.log(guess_mm), lo), hi)
    best: tuple[FieldPlan, float] | None = None
    missing = -1   # the most stations a looser target's plan bought without meeting the aim
    at_lo: float | None = None   # the log forecast at the bracket's ends (None: not forecast)
    at_hi: float | None = None
    extrapolated = False   # a step from one end's forecast alone was taken
    for _ in range(SEARCH_STEPS):
        more = plan(math.exp(t))
        bound = forecast(more) if more.count else None
        if bound is not None and bound <= aim_mm:
            best, lo, at_lo = (more, math.exp(t)), t, math.log(bound)
        else:
            hi, missing = t, max(missing, more.count)
            at_hi = None if bound is None else math.log(bound)
        if best is not None and (hi - lo <= math.log1p(SEARCH_WITHIN) or best[0].count <= missing + 1):
            break
        one_sided = (at_lo is None) != (at_hi is None)
        t = _next_target(lo, hi, at_lo, at_hi, math.log(aim_mm), one_sided and not extrapolated)
        extrapolated |= one_sided
    if best is not None:
        return best
    otherwise = plan_target_mm * floor if otherwise_mm is None else otherwise_mm
    return plan(otherwise), otherwise
