"""The run's bound forecast before the stations are touched, and the rounds it sizes: the
expected information against its closed form and against the spread of the learned values
over drawn fields, the forecast against the bound of the stations themselves, the search,
and the sequential planner against a plan that knows the part's prior, on a part with a
long error wavelength (the truth: the as-made part's analytic error)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.probing.deviation_prior import DeviationPrior, Sites, path_sites
from app.probing.field import plan_field
from app.probing.selection import PlanParams
from app.reconstruction.field_forecast import expected_log_sd, forecast_run_bound, plan_for_bound
from app.reconstruction.field_learning import learn_prior
from app.reconstruction.field_sequential import plan_sequential, stations_check
from app.reference.s1 import as_made, nominal_path, s1_traces
from tests.helpers.field_draws import draw

DEFAULT = PlanParams()


@pytest.fixture(scope="module")
def paths():
    return [nominal_path(t, 0.05) for t in s1_traces()[:7]]


def test_the_amplitudes_expected_sd_from_independent_touches_is_the_closed_form():
    """Touches 300 mm apart on a 3 mm wavelength are independent (jinc ~ 0), the placement
    terms off: K = (rms^2 + sigma^2) I, and the information of log A alone is
    2 n (rms^2 / (rms^2 + sigma^2))^2."""
    prior = DeviationPrior(amplitude_mm=0.03, wavelength_mm=3.0, placement_xy_mm=0.0, placement_z_mm=0.0,
                           placement_rz_deg=0.0, tilt_rad=0.0, sigma_mm=0.004)
    gx, gy = np.meshgrid(np.arange(6) * 300.0, np.arange(5) * 300.0)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    sites = Sites(xy, np.zeros_like(xy))
    rms2, noise2 = prior.rms_mm ** 2, prior.sigma_mm ** 2
    closed = math.sqrt(1.0 / (2 * len(xy))) * (rms2 + noise2) / rms2
    sd = expected_log_sd(prior, sites, xy.mean(axis=0), free=(True, False, False))
    assert sd[0] == pytest.approx(closed, rel=1e-3)
    assert np.isnan(sd[1:]).all()


def test_the_expected_sd_is_the_spread_of_the_learned_amplitude_over_drawn_fields():
    """30 touches of fields drawn from a known prior: the learned amplitude's log error over
    the draws has about the rms the expected information forecasts (the ML estimate is
    efficient: no estimator does much better from these touches)."""
    truth = DeviationPrior(amplitude_mm=0.12, wavelength_mm=10.0, sigma_mm=0.002)
    errors, forecast = [], []
    for seed in range(12):
        sites, center, dz = draw(truth, 30, 30_000 + seed, pairs=6)
        errors.append(math.log(learn_prior(DeviationPrior(), sites, dz, center).prior.amplitude_mm / 0.12))
        forecast.append(expected_log_sd(truth, sites, center)[0])
    rms = math.sqrt(float(np.mean(np.square(errors))))
    assert 0.6 * np.median(forecast) < rms < 1.6 * np.median(forecast)
    assert 0.1 < np.median(forecast) < 0.3   # 30 touches hold the amplitude to 10-30 %, not better



def test_the_amplitudes_information_saturates_with_the_parts_area_not_the_touches():
    """A 15 mm field over 40 x 30 mm: 16 x the touches (30 -> 480) do not bring the amplitude's
    expected sd under 10 %, while the wavelength's falls about as 1 / sqrt(n) (the area holds a few
    dozen independent values of the field, whatever touches them)."""
    truth = DeviationPrior(amplitude_mm=0.06, wavelength_mm=15.0, sigma_mm=0.002)
    few = expected_log_sd(truth, *draw(truth, 30, 1, pairs=6)[:2])
    many = expected_log_sd(truth, *draw(truth, 480, 2, pairs=96)[:2])
    assert many[0] > 0.1 and many[0] > 0.5 * few[0]
    assert many[1] < 0.4 * few[1]

@pytest.mark.parametrize("hyper", ["corner", "ellipse"])
def test_the_forecast_for_the_stations_touched_is_the_bound_they_give(paths, hyper, monkeypatch):
    """Nothing added: the forecast is the run's bound the verdict computes for the same
    stations and learning (the posterior sd does not depend on what the stations read), the
    learning's sd within the expected-information sd of its touches (the forecast's cap: the
    Laplace sd taken at most that); with either allowance for the hyperparameters' uncertainty."""
    from dataclasses import replace

    from app.reconstruction import field_trust

    monkeypatch.setattr(field_trust, "HYPER_BOUND", hyper)

    made = as_made(seed=3, amplitude_mm=0.15, min_wavelength_mm=25.0)
    plan = plan_field(paths, DEFAULT)
    dz = made.machining_error(plan.xy) + np.random.default_rng(3).normal(0.0, 0.001, plan.count)
    learned = learn_prior(DEFAULT.prior(), plan.sites, dz, plan.center)
    learned = replace(learned, log_sd=np.minimum(learned.log_sd, expected_log_sd(learned.prior, plan.sites,
                                                                                   plan.center)))
    check = stations_check(DEFAULT.prior(), plan.sites, dz, plan.center, plan.trace, plan.s_mm, paths,
                           DEFAULT.coverage, DEFAULT.target_error_mm, learned)
    assert not check.fit.outliers and not learned.screened
    forecast = forecast_run_bound(learned, plan.sites, plan.sites, plan.center, paths, DEFAULT.coverage)
    assert forecast == pytest.approx(check.bound_mm, rel=1e-9)
    more = plan_field(paths, PlanParams(target_error_mm=0.003), fixed=plan.sites)
    after = Sites(np.concatenate([plan.sites.xy, more.xy]), np.concatenate([plan.sites.grad, more.grad]))
    assert more.count and forecast_run_bound(learned, plan.sites, after, plan.center, paths,
                                             DEFAULT.coverage) < forecast   # more stations: a smaller bound


def test_a_round_is_the_fewest_stations_whose_forecast_is_within_the_aim():
    from types import SimpleNamespace

    def plan(t: float) -> SimpleNamespace:   # a target t buys ceil(10 / t) stations
        return SimpleNamespace(count=math.ceil(10.0 / t))

    def forecast(more: SimpleNamespace) -> float:   # ... and a bound of 20 / stations
        return 20.0 / more.count
    more, target = plan_for_bound(plan, forecast, 2.0, 5.0, 5.0)   # the aim 5: 4 stations, t in [2.5, 3.33)
    assert more.count == 4 and 2.5 <= target < 10.0 / 3.0
    more, target = plan_for_bound(plan, forecast, 2.0, 5.0, 0.1)   # out of reach: the tightest target
    assert target == pytest.approx(1.0) and more.count == 10


def test_a_forecast_sd_is_at_most_the_expected_information_sd_of_the_design(paths):
    """A pilot's Laplace sd scattered far over the expected-information sd of its own touches
    (here made 3 x): the forecast sd for a design is no more than that design's expected
    information gives (the Cramer-Rao forecast), and no more than the scaled Laplace sd when
    that is the smaller."""
    from dataclasses import replace

    from app.reconstruction.field_forecast import forecast_learned

    made = as_made(seed=3, amplitude_mm=0.15, min_wavelength_mm=25.0)
    plan = plan_field(paths, DEFAULT)
    dz = made.machining_error(plan.xy) + np.random.default_rng(3).normal(0.0, 0.001, plan.count)
    learned = learn_prior(DEFAULT.prior(), plan.sites, dz, plan.center)
    assert not any(learned.at_bound)
    more = plan_field(paths, PlanParams(target_error_mm=0.003), fixed=plan.sites)
    after = Sites(np.concatenate([plan.sites.xy, more.xy]), np.concatenate([plan.sites.grad, more.grad]))
    fisher_now = expected_log_sd(learned.prior, plan.sites, plan.center)
    fisher_after = expected_log_sd(learned.prior, after, plan.center)
    wide = replace(learned, log_sd=3.0 * fisher_now)
    forecast = forecast_learned(wide, plan.sites, after, plan.center)
    narrow = forecast_learned(replace(learned, log_sd=0.5 * fisher_now), plan.sites, after, plan.center)
    for i, name in enumerate(("amplitude_mm", "wavelength_mm")):
        assert forecast[name]["relative_sd"] == pytest.approx(math.expm1(fisher_after[i]), rel=1e-9)
        assert narrow[name]["relative_sd"] == pytest.approx(math.expm1(0.5 * fisher_after[i]), rel=1e-9)


def test_the_search_ends_once_no_station_fewer_can_meet_the_aim():
    """The same plans as above: 2 and 2.5 buy 5 stations (bound 4), 3.54 buys 3 and misses,
    2.91 buys 4 (bound 5: the aim); no plan lies between 4 and 3 stations, the search ends
    there (4 plans, not SEARCH_STEPS) with the same answer."""
    from types import SimpleNamespace

    from app.reconstruction.field_forecast import SEARCH_STEPS
    targets: list[float] = []

    def plan(t: float) -> SimpleNamespace:
        targets.append(t)
        return SimpleNamespace(count=math.ceil(10.0 / t))
    more, target = plan_for_bound(plan, lambda m: 20.0 / m.count, 2.0, 5.0, 5.0)
    assert more.count == 4 and 2.5 <= target < 10.0 / 3.0
    assert len(targets) == 4 < SEARCH_STEPS


def test_a_rounds_forecast_computes_the_touched_stations_information_once(paths, monkeypatch):
    """A round's search forecasts many designs from the same touches: the expected information
    of the touched stations is computed once, each design's once (k forecasts: k + 1), and the
    forecast is the same as computed afresh."""
    import app.reconstruction.field_forecast as field_forecast
    import app.reconstruction.field_sequential as field_sequential
    from app.reconstruction.field_sequential import round_forecast

    made = as_made(seed=3, amplitude_mm=0.15, min_wavelength_mm=25.0)
    plan = plan_field(paths, DEFAULT)
    dz = made.machining_error(plan.xy) + np.random.default_rng(3).normal(0.0, 0.001, plan.count)
    learned = learn_prior(DEFAULT.prior(), plan.sites, dz, plan.center)
    current = PlanParams(deviation_amplitude_mm=learned.prior.amplitude_mm,
                         deviation_wavelength_mm=learned.prior.wavelength_mm, target_error_mm=0.003)
    designs = [plan_field(paths, PlanParams(target_error_mm=t), fixed=plan.sites) for t in (0.004, 0.003, 0.002)]
    calls = []
    counted = field_forecast.expected_log_sd

    def counting(*args, **kwargs):
        calls.append(len(args[1].xy))
        return counted(*args, **kwargs)
    monkeypatch.setattr(field_forecast, "expected_log_sd", counting)
    monkeypatch.setattr(field_sequential, "expected_log_sd", counting, raising=False)
    forecast = round_forecast(learned, plan.sites, plan.center, paths, DEFAULT, current)
    assert forecast is not None
    values = [forecast(more) for more in designs]
    assert len(calls) == len(designs) + 1 and calls.count(plan.count) == 1
    for more, value in zip(designs, values):
        after = Sites(np.concatenate([plan.sites.xy, more.xy]), np.concatenate([plan.sites.grad, more.grad]))
        assert value == pytest.approx(counted_bound(learned, plan, after, paths), rel=1e-12)


def counted_bound(learned, plan, after: Sites, paths) -> float:
    """The forecast afresh (the touched stations' information computed again)."""
    return forecast_run_bound(learned, plan.sites, after, plan.center, paths, DEFAULT.coverage,
                              DEFAULT.probe_sigma_mm)


def test_sequential_planning_on_a_long_wavelength_part_uses_at_most_1_3x_the_touches_of_a_plan_that_knows_it(paths):
    """A held-out as-made part (six plane waves of 25-75 mm, peak 0.164 mm), the user's prior
    at the defaults: the sequential plan's touches within 1.3 x those of the single-shot plan
    for the part's true shortest wavelength and amplitude (+ the same 5 verification points),
    called verified, and every trace within its bound against the part's analytic truth."""
    made = as_made(seed=626, amplitude_mm=0.164, min_wavelength_mm=25.0)
    rng = np.random.default_rng(626)
    result = plan_sequential(paths, DEFAULT, lambda xy: made.machining_error(xy) + rng.normal(0.0, 0.001, len(xy)))
    oracle = plan_field(paths, PlanParams(deviation_amplitude_mm=0.164, deviation_wavelength_mm=25.0)).count + 5
    assert result.stopped == "bound holds" and not result.check.needs_attention
    assert result.touches <= 1.3 * oracle
    for p, bound in zip(paths, result.trace_bounds_mm):
        sites = path_sites(p, p.s[::2])
        truth = made.machining_error(sites.xy)
        assert np.abs(result.check.fit.deviation(sites) - truth).max() <= bound < np.abs(truth).max()


def test_a_round_after_a_missed_forecast_tightens_at_most_by_half():
    from types import SimpleNamespace

    from app.reconstruction.field_sequential import TIGHTEN_MIN, tighten_round

    def plan(t: float) -> SimpleNamespace:
        return SimpleNamespace(count=math.ceil(10.0 / t))

    def never(more: SimpleNamespace) -> float:   # a forecast no plan meets
        return 100.0
    _, first = tighten_round(plan, never, 5.0, 5.0, 20.0)
    _, again = tighten_round(plan, never, 5.0, 5.0, 20.0, missed=True)
    assert first == pytest.approx(1.0) and again == pytest.approx(5.0 * TIGHTEN_MIN)
    _, proportional = tighten_round(plan, None, 5.0, 5.0, 20.0)   # no forecast: aim / bound, at most halved
    assert proportional == pytest.approx(2.5)



def test_a_bound_proportional_to_the_target_is_met_in_one_step_from_a_miss():
    """The bound a target buys exactly proportional to it (1.5 x the target): from a guess
    that misses the aim, the step at slope 1 in log-log lands on aim / 1.5 itself, within the
    aim; the next step (between the two forecasts, kept SEARCH_GUARD of the bracket inside)
    misses, and the bracket is then within SEARCH_WITHIN: three plans."""
    from types import SimpleNamespace

    from app.reconstruction.field_forecast import SEARCH_GUARD, SEARCH_WITHIN
    targets: list[float] = []

    def plan(t: float) -> SimpleNamespace:
        targets.append(t)
        return SimpleNamespace(count=math.ceil(100.0 / t), target=t)
    more, target = plan_for_bound(plan, lambda m: 1.5 * m.target, 5.0, 6.25, 6.0)
    assert targets[1] == pytest.approx(4.0, rel=1e-12) and target == targets[1] and more.target == target
    assert targets[2] == pytest.approx(4.0 * (5.0 / 4.0) ** SEARCH_GUARD, rel=1e-12)
    assert len(targets) == 3 and targets[2] / target <= 1 + SEARCH_WITHIN


def test_the_next_target_meets_the_aim_on_a_power_law_and_keeps_inside_the_bracket():
    """A forecast c t^p (a line in log-log): the step between its two ends' forecasts is the
    target whose forecast is the aim (to rounding), unless that lies within SEARCH_GUARD of an
    end; one end's forecast alone gives the slope-1 step when allowed, else the middle."""
    from app.reconstruction.field_forecast import SEARCH_GUARD, _next_target

    def log_forecast(t: float) -> float:   # 0.8 t^1.7, log target in, log forecast out
        return math.log(0.8) + 1.7 * t
    lo, hi = math.log(2.0), math.log(6.0)
    aim = log_forecast(math.log(3.5))
    assert _next_target(lo, hi, log_forecast(lo), log_forecast(hi), aim, False) == pytest.approx(math.log(3.5))
    near = log_forecast(math.log(2.05))
    assert _next_target(lo, hi, log_forecast(lo), log_forecast(hi), near, False) == \
        pytest.approx(lo + SEARCH_GUARD * (hi - lo))
    assert _next_target(lo, hi, None, log_forecast(hi), aim, True) == pytest.approx(hi + aim - log_forecast(hi))
    assert _next_target(lo, hi, None, log_forecast(hi), aim, False) == pytest.approx(0.5 * (lo + hi))
    assert _next_target(lo, hi, None, None, aim, True) == pytest.approx(0.5 * (lo + hi))
