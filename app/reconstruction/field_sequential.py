"""Sequential field planning: pilot, learn the prior, add stations until the run's bound
under the fitted model meets the target (or a touch budget is spent), then verify.

A single-shot field plan (:func:`app.probing.field.plan_field`) is only as good as the prior
it was designed for.  When the prior is uncertain:

1. **pilot**: a coarse field plan (:func:`pilot_params`: the user's amplitude and noise, twice
   the user's wavelength): the fewest touches any part needs, so a smooth part costs no more
   than a plan for its true prior would;
2. **learn**: the prior's amplitude, wavelength and noise by type-II ML from every touch so
   far (:func:`app.reconstruction.field_learning.learn_prior`, gross outliers screened out);
3. **add**: the field planner again, for the learned prior (:func:`round_params`), starting
   from every station already touched (``fixed``): it returns only the stations the fitted
   posterior still needs for ``coverage`` x sd <= the round's pointwise target on every trace
   point; the first round after the pilot for the loosest pointwise target whose stations'
   forecast run's bound is within the aim (:func:`first_round`), later rounds for the target
   the previous one planned for;
4. **the run's bound**: when it adds none, the stations are fitted and bounded as the verdict
   does it (:func:`stations_check`: the learned prior, the hyperparameters' own uncertainty,
   the run's traces sharing the confidence, :func:`app.reconstruction.field_trust.run_bounds`);
   a bound within the verdict's tolerance (``bound_meets_target``) ends the rounds, one over
   it tightens the pointwise target and the round plans again, as many stations as the
   forecast of the bound they will give asks for (:func:`tighten_round`,
   :mod:`app.reconstruction.field_forecast`);
5. repeat 2-4 until the bound holds, ``max_rounds`` pass, or the next round would pass
   ``budget`` touches (the result says which); one round's decision is :func:`decide_round`,
   the same for the loop here and for the ``probe_plan`` job's round between probe runs;
6. **verify**: ``verify_count`` points where the fitted posterior is least certain, and the
   gaps beside the stations the others predict worst, each with its spot left out
   (:mod:`app.reconstruction.field_surprise`: where a step or another structure the smooth
   field cannot represent shows: :func:`app.probing.field_verify.gap_points`),
   touched last and never fitted (:mod:`app.reconstruction.field_trust`).

``measure(xy (m, 2)) -> dz (m,)`` touches points and returns the measured deviation (mm):
the mock's truth plus noise in the bench, a probe run on a machine.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from app.geometry.traces import as_trace_polyline
from app.probing.deviation_prior import DeviationPrior, Sites
from app.probing.field import FieldPlan, plan_field
from app.probing.field_reuse import PlanReuse
from app.probing.field_verify import with_sequential_verification
from app.probing.selection import PlanParams
from app.reconstruction.field_forecast import (
    SEARCH_FLOOR,
    expected_log_sd,
    forecast_run_bound,
    learned_free,
    plan_for_bound,
)
from app.reconstruction.field_learning import MIN_TOUCHES, NOISE_MISFIT, LearnedPrior, learn_prior
from app.reconstruction.field_surprise import surprise
from app.reconstruction.field_trust import (
    TARGET_SLACK,
    FieldCheck,
    bound_meets_target,
    checked_field,
    run_bounds,
    with_bound,
)

MAX_ROUNDS = 6
DEFAULT_BUDGET = 2000
PILOT_WAVELENGTH_FACTOR = 2.0  # the pilot plans for twice the user's wavelength
SHRINK_PER_ROUND = 2.0         # a round plans for no less than the previous round's wavelength / 2
TIGHTEN_MIN = 0.5              # a round's pointwise target is at most halved at once
BOUND_AIM = 1.0                # a tightened round aims the run's bound at this fraction of the verdict's tolerance


def pilot_params(params: PlanParams) -> PlanParams:
    """The pilot's plan parameters: ``params`` with twice the wavelength (a coarse design
    any part needs; the rounds add what the learned prior asks for).  A pilot of fewer than
    ``MIN_TOUCHES`` stations (a small board) is replaced by the user's own design: the prior
    cannot be learned from fewer."""
    return replace(params, deviation_wavelength_mm=params.deviation_wavelength_mm * PILOT_WAVELENGTH_FACTOR)


def round_params(params: PlanParams, learned: DeviationPrior, previous_wavelength_mm: float) -> PlanParams:
    """A round's plan parameters: the ``learned`` amplitude and wavelength, the wavelength no
    shorter than ``previous_wavelength_mm`` / SHRINK_PER_ROUND (stations far apart alias a
    short field into any wavelength: the plan refines step by step); the noise the probe's
    (``params``: its repeatability; a learned noise a little over it is the estimate's own
    scatter and would buy stations to average it; one over NOISE_MISFIT x it is structure the
    stations do not resolve: it asks for a finer plan, and the wavelength is then halved).
    The fit and its bound still use the learned noise."""
    user_sigma = params.probe_sigma_mm
    wavelength = max(learned.wavelength_mm, previous_wavelength_mm / SHRINK_PER_ROUND)
    if learned.sigma_mm > NOISE_MISFIT * user_sigma:
        wavelength = previous_wavelength_mm / SHRINK_PER_ROUND
    return replace(params, deviation_amplitude_mm=learned.amplitude_mm, deviation_wavelength_mm=wavelength,
                   probe_sigma_mm=user_sigma)


def bound_aim(target_mm: float) -> float:
    """Where a round aims the run's bound (mm): BOUND_AIM x the verdict's tolerance."""
    return BOUND_AIM * TARGET_SLACK * target_mm


def round_forecast(learned: LearnedPrior, sites: Sites, center: np.ndarray, paths: Sequence[object],
                   params: PlanParams, current: PlanParams,
                   bound_mm: float | None = None) -> Callable[[FieldPlan], float] | None:
    """The forecast of the run's bound after a round's stations (``plan`` -> mm,
    :func:`app.reconstruction.field_forecast.forecast_run_bound`) under the prior ``learned``
    from the touches at ``sites`` (n,), for the probe's noise as the round plans for it (a
    learned noise a little over the probe's is mostly structure the stations do not resolve
    yet, and falls as they are added).  ``bound_mm``: the stations' own run's bound, given when
    the forecast missed once (an earlier round was tightened for the bound, and it is over the
    tolerance again): the forecast is then scaled to give it for the stations touched (the
    learned noise did not fall, or a touch was excluded).  None when the round does not plan
    for the learned prior (``current``: its wavelength held at the previous round's half, or a
    learned noise over NOISE_MISFIT x the probe's: the stations do not resolve the field yet,
    and the next round learns again).  The learning's screened touches are left out of its
    information."""
    if current.deviation_wavelength_mm != learned.prior.wavelength_mm \
            or learned.prior.sigma_mm > NOISE_MISFIT * params.probe_sigma_mm:
        return None
    learned_from = sites.take(np.setdiff1d(np.arange(len(sites.xy)), learned.screened))
    now = expected_log_sd(learned.prior, learned_from, center, learned_free(learned))  # once for every design

    def unscaled(after: Sites) -> float:
        return forecast_run_bound(learned, learned_from, after, center, paths, params.coverage,
                                  params.probe_sigma_mm, now)
    scale = 1.0 if bound_mm is None else max(1.0, bound_mm / unscaled(sites))

    def forecast(more: FieldPlan) -> float:
        return scale * unscaled(Sites(np.concatenate([sites.xy, more.xy]), np.concatenate([sites.grad, more.grad])))
    return forecast


def tightened_target(plan_target_mm: float, target_mm: float, bound_mm: float) -> float:
    """The next round's pointwise target (mm) when the run's bound ``bound_mm`` under the
    fitted model is over the verdict's tolerance after a round planned for ``plan_target_mm``:
    scaled by aim / bound, the aim BOUND_AIM x the tolerance (TARGET_SLACK x the target; the
    bound scales about as the pointwise sd between the stations does, and stations come whole,
    so the bound lands at or under the aim: inside the tolerance, without buying the stations
    a bound at the target itself would cost; a round that lands over it is followed by a small
    one); at most halved at once (TIGHTEN_MIN).  Mm in, mm out."""
    aim = BOUND_AIM * TARGET_SLACK * target_mm
    return plan_target_mm * max(TIGHTEN_MIN, min(1.0, aim / bound_mm))


TIGHTEN_TRIES = 3  # a tightened round that adds no station is tightened again, this many times in all


def plan_tightened(plan: Callable[[float], FieldPlan], plan_target_mm: float, target_mm: float,
                   bound_mm: float) -> tuple[FieldPlan, float]:
    """(the stations ``plan(pointwise target mm)`` adds, the target it planned for) after a
    round whose run's bound ``bound_mm`` is over the verdict's tolerance: the target tightened
    (:func:`tightened_target`) until the plan adds a station, at most TIGHTEN_TRIES times (a
    learned noise far over the probe's can keep the bound over the target whatever is added:
    then none, and the rounds end)."""
    for _ in range(TIGHTEN_TRIES):
        plan_target_mm = tightened_target(plan_target_mm, target_mm, bound_mm)
        more = plan(plan_target_mm)
        if more.count:
            break
    return more, plan_target_mm


def tighten_round(plan: Callable[[float], FieldPlan], forecast: Callable[[FieldPlan], float] | None,
                  plan_target_mm: float, target_mm: float, bound_mm: float,
                  missed: bool = False) -> tuple[FieldPlan, float]:
    """(the stations a round adds, the pointwise target it planned for) after a round whose
    run's bound ``bound_mm`` is over the verdict's tolerance: sized by the ``forecast`` of the
    bound its stations will give (:func:`round_forecast`: the loosest target whose stations'
    forecast is within :func:`bound_aim`, :func:`app.reconstruction.field_forecast.plan_for_bound`,
    searched from :func:`tightened_target`); without a forecast, :func:`plan_tightened`."""
    if forecast is None:
        return plan_tightened(plan, plan_target_mm, target_mm, bound_mm)
    return plan_for_bound(plan, forecast, tightened_target(plan_target_mm, target_mm, bound_mm), plan_target_mm,
                          bound_aim(target_mm), TIGHTEN_MIN if missed else SEARCH_FLOOR)


def stations_check(prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray, trace: np.ndarray,
                   s_mm: np.ndarray, paths: Sequence[object], coverage: float, target_mm: float,
                   learned: LearnedPrior | None = None) -> FieldCheck:
    """The checked field of the stations touched so far, without verification points, its
    bound the run's (:func:`app.reconstruction.field_trust.run_bounds` over ``paths``): the
    verdict's own fit and bound of these touches.  sites / dz / trace / s_mm (n,): the
    stations, their measured deviation (mm), trace index and arc length (mm); ``learned``:
    ``learn_prior(prior, sites, dz, center)`` when the caller has it (not learned again)."""
    n = len(sites.xy)
    check = checked_field(prior, sites, np.zeros(n), np.column_stack([sites.xy, dz]), center, trace, s_mm,
                          np.zeros(n, dtype=bool), coverage, target_mm, learned_first=learned)
    return with_bound(check, run_bounds(check, paths))


def first_round(params: PlanParams, learned: LearnedPrior, sites: Sites, center: np.ndarray,
                paths: Sequence[object], plan: Callable[[PlanParams], FieldPlan], current: PlanParams,
                at_target: FieldPlan) -> tuple[FieldPlan, PlanParams]:
    """(the stations, the round's plan parameters) of the first round after the pilot, whose
    plan ``at_target`` for the ``learned`` prior at the user's pointwise target adds stations:
    sized by the forecast of the run's bound (:func:`round_forecast`) as a round after a bound
    over the tolerance is: the loosest pointwise target in [SEARCH_FLOOR x the target,
    :func:`bound_aim`) whose stations' forecast is within the aim
    (:func:`app.reconstruction.field_forecast.plan_for_bound`, searched from the target), not
    the stations the target buys whatever bound they give.  ``at_target`` as it is when the
    round does not plan for the learned prior (no forecast: the pilot does not resolve the
    field) or no target searched meets the aim."""
    forecast = round_forecast(learned, sites, center, paths, params, current)
    if forecast is None:
        return at_target, current
    target, aim = params.target_error_mm, bound_aim(params.target_error_mm)

    def replan(t: float) -> FieldPlan:
        return at_target if math.isclose(t, target) else plan(replace(current, target_error_mm=t))
    more, sized = plan_for_bound(replan, forecast, target, aim, aim, SEARCH_FLOOR * target / aim, target)
    return more, replace(current, target_error_mm=sized)


@dataclass(frozen=True)
class Round:
    """A round's decision (:func:`decide_round`).  more: the stations it adds (count 0: none);
    params: its plan parameters (the learned prior as :func:`round_params` plans for it,
    ``target_error_mm`` the pointwise target it planned for); bound_mm: the run's bound of the
    stations touched so far (mm; None: not computed, the round added stations at its target);
    stopped: why the rounds end here ("bound holds", "no station helps", "budget"), None: they
    go on with ``more``."""

    more: FieldPlan
    params: PlanParams
    bound_mm: float | None
    stopped: str | None


def decide_round(params: PlanParams, learned: LearnedPrior, sites: Sites, dz: np.ndarray, trace: np.ndarray,
                 s_mm: np.ndarray, center: np.ndarray, paths: Sequence[object],
                 plan: Callable[[PlanParams], FieldPlan], plan_target_mm: float, previous_wavelength_mm: float,
                 room: int | None = None, judge: bool = True, first: bool = False) -> Round:
    """One round after the touches so far (steps 3-4 of the module doc): the stations the
    fitted field still needs for the ``learned`` prior (:func:`round_params` from the previous
    round's ``previous_wavelength_mm``) at the pointwise target ``plan_target_mm`` (mm); with
    none, the run's bound of the touched stations (:func:`stations_check`): within the
    verdict's tolerance ends the rounds, over it tightens the target (:func:`tighten_round`,
    sized by :func:`round_forecast`).  ``params``: the user's plan parameters (the target, the
    coverage, the probe's noise); sites / dz / trace / s_mm (n,): the stations touched, their
    measured deviation (mm), trace index and arc length (mm); ``center`` (2,): the field's
    centre; ``paths``: the TracePolylines; ``plan(round parameters)``: the field planner from
    the touched stations (``fixed``), only the stations it adds; ``room``: the most stations
    the round may add within the touch budget (None: no budget); ``judge``: False when the
    bound is not to be computed this round (a suspected outlier is touched again first);
    ``first``: the first round after the pilot (or the user's own first design), whose
    stations are sized by the forecast when it adds any (:func:`first_round`)."""
    target = params.target_error_mm
    current = replace(round_params(params, learned.prior, previous_wavelength_mm), target_error_mm=plan_target_mm)
    more = plan(current)
    bound = None
    if first and more.count:
        more, current = first_round(params, learned, sites, center, paths, plan, current, more)
    if more.count == 0 and judge:
        bound = stations_check(params.prior(), sites, dz, center, trace, s_mm, paths, params.coverage, target,
                               learned).bound_mm
        if bound_meets_target(bound, target):
            return Round(more, current, bound, "bound holds")
        missed = plan_target_mm != target  # an earlier round was sized for the bound already
        forecast = round_forecast(learned, sites, center, paths, params, current, bound if missed else None)

        def replan(t: float, at: PlanParams = current) -> FieldPlan:
            return plan(replace(at, target_error_mm=t))
        more, tightened = tighten_round(replan, forecast, plan_target_mm, target, bound, missed)
        current = replace(current, target_error_mm=tightened)
        if more.count == 0:
            return Round(more, current, bound, "no station helps")
    if room is not None and more.count > room:
        return Round(more, current, bound, "budget")
    return Round(more, current, bound, None)


@dataclass(frozen=True)
class SequentialResult:
    """check: the verified field (its bound: the largest trace bound under the fitted model); stations: every
    fitted station (n,); rounds: stations added per round (the pilot first); stopped: why the rounds ended ("bound
    holds": the run's bound within the verdict's tolerance, "budget", "rounds", "no station
    helps": the target tightened TIGHTEN_TRIES times and still nothing added); params: the
    plan parameters of the last round (its ``target_error_mm`` the pointwise target it planned for);
    trace_bounds_mm (T,): each trace's bound (:func:`app.reconstruction.field_trust.trace_bound`)."""

    check: FieldCheck
    stations: Sites
    trace: np.ndarray
    s_mm: np.ndarray
    rounds: tuple[int, ...]
    stopped: str
    params: PlanParams
    trace_bounds_mm: tuple[float, ...] = ()

    @property
    def touches(self) -> int:
        v = self.check.verification
        return len(self.stations.xy) + (0 if v is None else len(v.xy))


def plan_sequential(nominals: Sequence[object], params: PlanParams,
                    measure: Callable[[np.ndarray], np.ndarray], budget: int = DEFAULT_BUDGET,
                    verify_count: int = 5, max_rounds: int = MAX_ROUNDS) -> SequentialResult:
    """Pilot, learn, add, verify (see the module doc).  ``nominals``: the traces (one frame)."""
    paths = [as_trace_polyline(n, field=f"traces[{i}]") for i, n in enumerate(nominals)]
    user = params.prior()
    current = pilot_params(params)
    plan = plan_field(paths, current)
    if plan.count < MIN_TOUCHES:  # too coarse to learn the prior from: the user's own design
        current = params
        plan = plan_field(paths, current)
    sites, trace, s, z = plan.sites, plan.trace, plan.s_mm, plan.z
    dz = np.asarray(measure(plan.xy), dtype=float)
    rounds = [plan.count]
    stopped = "rounds"
    center = plan.center
    plan_target = params.target_error_mm
    learned: LearnedPrior | None = None  # the last learning, while no touch was added after it
    for _ in range(max_rounds):
        if len(dz) < MIN_TOUCHES:
            break

        shared = PlanReuse()   # what this round's plans share

        def planned(at: PlanParams, touched: Sites = sites, reuse: PlanReuse = shared) -> FieldPlan:
            return plan_field(paths, at, fixed=touched, reuse=reuse)
        learned = learn_prior(user, sites, dz, center)
        decision = decide_round(params, learned, sites, dz, trace, s, center, paths,
                                planned, plan_target, current.deviation_wavelength_mm,
                                room=budget - len(dz) - verify_count, first=len(rounds) == 1)
        more, current, plan_target = decision.more, decision.params, decision.params.target_error_mm
        if decision.stopped is not None:
            stopped = decision.stopped
            break
        rounds.append(more.count)
        sites = Sites(np.concatenate([sites.xy, more.xy]), np.concatenate([sites.grad, more.grad]))
        trace = np.concatenate([trace, more.trace])
        s = np.concatenate([s, more.s_mm])
        z = np.concatenate([z, more.z])
        dz = np.concatenate([dz, np.asarray(measure(more.xy), dtype=float)])
        learned = None
    prior_now = current.prior()
    surprised = surprise(prior_now, sites, dz, center, trace, s) if len(dz) >= MIN_TOUCHES else None
    empty = replace(plan, xy=plan.xy[:0], z=plan.z[:0], grad=plan.grad[:0], trace=plan.trace[:0],
                    s_mm=plan.s_mm[:0], order=plan.order[:0])
    points = with_sequential_verification(empty, sites, paths, prior_now, verify_count, surprised)
    v_dz = np.asarray(measure(points.xy), dtype=float) if points.count else np.zeros(0)
    all_sites = Sites(np.concatenate([sites.xy, points.xy]), np.concatenate([sites.grad, points.grad]))
    n = len(sites.xy)
    nominal_z = np.zeros(n + points.count)
    measured = np.column_stack([all_sites.xy, np.concatenate([dz, v_dz])])
    mask = np.concatenate([np.zeros(n, dtype=bool), np.ones(points.count, dtype=bool)])
    check = checked_field(user, all_sites, nominal_z, measured, center,
                          np.concatenate([trace, points.trace]), np.concatenate([s, points.s_mm]), mask,
                          params.coverage, params.target_error_mm, learned_first=learned)
    bounds = run_bounds(check, paths)
    return SequentialResult(with_bound(check, bounds), sites, trace, s, tuple(rounds), stopped, current, bounds)
