"""A field checked against the part before printing: verification points, the bound under
the learned model, and sequential planning, on a part whose error is shorter than the
default prior's wavelength (0.12 sin(2 pi x/22) sin(2 pi y/18) + 0.05 cos(2 pi (x+y)/35) mm:
~14 mm effective wavelength against the default 20 mm)."""

from __future__ import annotations

import numpy as np
import pytest

from app.probing.deviation_prior import path_sites
from app.probing.field import plan_field, posterior_sd
from app.probing.field_region import field_region
from app.probing.field_verify import verification_indices, with_verification
from app.probing.selection import PlanParams
from app.reconstruction.field_sequential import plan_sequential
from app.reconstruction.field_trust import TARGET_SLACK, checked_field, run_bounds, trace_bound, with_bound
from app.reference.s1 import nominal_path, s1_traces

DEFAULT = PlanParams()  # the user's prior left at the defaults: A 0.2 mm, lambda 20 mm, target 5 um, coverage 3
NOISE_MM = 0.001


def fourteen(xy: np.ndarray) -> np.ndarray:
    """The as-made part's error (m,) mm at xy (m, 2): the analytic truth."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.12 * np.sin(2 * np.pi * x / 22) * np.sin(2 * np.pi * y / 18) + 0.05 * np.cos(2 * np.pi * (x + y) / 35)


@pytest.fixture(scope="module")
def paths():
    return [nominal_path(t, 0.05) for t in s1_traces()[:7]]


def toucher(seed: int):
    rng = np.random.default_rng(seed)
    return lambda xy: fourteen(np.atleast_2d(xy)) + rng.normal(0.0, NOISE_MM, len(np.atleast_2d(xy)))


def true_errors(fit, paths) -> tuple[np.ndarray, np.ndarray]:
    """Per trace (T,): worst |model - truth| (the compensated program's standoff error, to the
    chord error) and worst |truth| (the nominal program's), mm, every 0.1 mm."""
    after, before = [], []
    for p in paths:
        sites = path_sites(p, p.s[::2])
        truth = fourteen(sites.xy)
        after.append(np.abs(fit.deviation(sites) - truth).max())
        before.append(np.abs(truth).max())
    return np.array(after), np.array(before)


def test_verification_points_are_where_the_posterior_is_least_certain_and_spread(paths):
    plan = plan_field(paths, DEFAULT)
    samples = field_region(paths, DEFAULT.deviation_wavelength_mm).samples
    idx = verification_indices(DEFAULT.prior(), plan.sites, samples.sites, plan.center, 5)
    sd = posterior_sd(DEFAULT.prior(), plan.sites, samples.sites, plan.center)
    assert sd[idx[0]] == pytest.approx(sd.max())             # the first: the least certain trace point
    assert len(set(idx.tolist())) == 5
    gaps = np.linalg.norm(samples.sites.xy[idx][:, None] - samples.sites.xy[idx][None], axis=2)
    assert gaps[~np.eye(5, dtype=bool)].min() > 1.0           # spread, not clustered at one spot
    verified = with_verification(plan, paths, DEFAULT.prior(), 5)
    assert verified.count == plan.count + 5 and verified.verify_mask[-5:].all() and not verified.verify_mask[:-5].any()
    assert np.array_equal(verified.stations_per_trace, plan.stations_per_trace)


def test_the_single_shot_default_plan_does_not_call_itself_done_on_the_14_mm_part(paths):
    plan = with_verification(plan_field(paths, DEFAULT), paths, DEFAULT.prior(), 5)
    dz = toucher(1)(plan.xy)
    check = checked_field(DEFAULT.prior(), plan.sites, np.zeros(plan.count), np.column_stack([plan.xy, dz]),
                          plan.center, plan.trace, plan.s_mm, plan.verify_mask, DEFAULT.coverage,
                          DEFAULT.target_error_mm)
    check = with_bound(check, [trace_bound(check.fit, p, DEFAULT.coverage) for p in paths])
    learned = check.learned["wavelength_mm"]["value"]
    assert 10.0 < learned < 17.0                               # learned from the touches, not the 20 mm told
    after, before = true_errors(check.fit, paths)
    assert (after < before).all()                              # never worse than the nominal program
    # the default plan is too sparse for this part: the fitted model says so, and the check asks for attention
    assert check.needs_attention and check.bound_mm > DEFAULT.target_error_mm
    assert after.max() <= check.bound_mm
    assert check.verified_line().startswith("verified at 5 points: max |residual|")


def test_sequential_planning_holds_every_trace_within_its_verified_bound_on_the_14_mm_part(paths):
    result = plan_sequential(paths, DEFAULT, toucher(2), verify_count=5)
    check = result.check
    assert result.stopped == "bound holds" and len(result.rounds) >= 2   # the pilot, then stations added
    # the rounds go on until the run's bound (the 7 traces sharing its confidence, the learned
    # amplitude and wavelength 2 sd on their unfavourable side) meets the target: verified
    assert check.bound_mm <= DEFAULT.target_error_mm * TARGET_SLACK and not check.needs_attention, check.reasons
    assert result.params.target_error_mm < DEFAULT.target_error_mm   # a round planned for a tightened pointwise target
    assert check.bound_mm == max(result.trace_bounds_mm) == pytest.approx(max(run_bounds(check, paths)))
    after, before = true_errors(check.fit, paths)
    assert (after < before).all()
    assert after.max() <= check.bound_mm
    assert (after <= np.array(result.trace_bounds_mm)).all()   # every trace within its own bound
    assert check.verification is not None and check.verification.within.all()
    assert check.verified_line().startswith(f"verified at {len(check.verification.xy)} points: max |residual| ")


def test_a_round_over_the_bound_tightens_its_pointwise_target_by_aim_over_bound():
    from types import SimpleNamespace

    from app.reconstruction.field_sequential import (
        BOUND_AIM,
        TIGHTEN_MIN,
        TIGHTEN_TRIES,
        plan_tightened,
        tightened_target,
    )

    aim = BOUND_AIM * TARGET_SLACK * 5.0  # at most the verdict's tolerance (the stopping rule is on the touched bound)
    assert 5.0 <= aim <= TARGET_SLACK * 5.0
    assert tightened_target(5.0, 5.0, 8.0) == pytest.approx(5.0 * aim / 8.0)   # aims the bound at the aim
    assert tightened_target(3.0, 5.0, 2 * aim) == pytest.approx(1.5)           # from the round's own target
    assert tightened_target(5.0, 5.0, 40.0) == pytest.approx(5.0 * TIGHTEN_MIN)  # at most halved at once
    assert tightened_target(5.0, 5.0, 4.0) == 5.0                               # never loosened
    asked: list[float] = []

    def plan(t: float) -> SimpleNamespace:
        asked.append(t)
        return SimpleNamespace(count=int(t < 2.0))   # adds a station only below 2
    more, target = plan_tightened(plan, 5.0, 5.0, 20.0)
    assert more.count == 1 and asked == [2.5, 1.25] and target == 1.25
    asked.clear()

    def nothing(t: float) -> SimpleNamespace:
        asked.append(t)
        return SimpleNamespace(count=0)
    more, target = plan_tightened(nothing, 5.0, 5.0, 20.0)
    assert more.count == 0 and len(asked) == TIGHTEN_TRIES   # tightened that often, then the rounds end


def stepped(xy: np.ndarray) -> np.ndarray:
    """The 14 mm part with a 20 um step up across x = 30 mm (a discontinuity the smooth field
    cannot represent): the truth (m,) mm at xy (m, 2)."""
    return fourteen(xy) + 0.02 * (xy[:, 0] > 30.0)


def test_a_step_in_the_part_is_not_verified_and_a_gap_point_reads_it(paths):
    """A 20 um step: the loop asks for attention (a verification point off its band, or the
    fit took the step for noise and its bound is over the target) and the verification point
    that reads most off the field is the gap point at the step."""
    rng = np.random.default_rng(4)
    result = plan_sequential(paths, DEFAULT,
                             lambda xy: stepped(np.atleast_2d(xy)) + rng.normal(0.0, NOISE_MM, len(np.atleast_2d(xy))),
                             verify_count=5)
    check = result.check
    worst_true = max(np.abs(check.fit.deviation(s) - stepped(s.xy)).max()
                     for s in (path_sites(p, p.s[::2]) for p in paths))
    assert worst_true > check.bound_mm                         # calling this verified would be false
    assert check.needs_attention
    v = check.verification
    worst = int(np.argmax(np.abs(v.residual_mm)))
    assert abs(v.xy[worst, 0] - 30.0) < 1.5                   # the gap point that reads most off the field: at the step
    assert not v.within.all() or check.bound_mm > DEFAULT.target_error_mm * TARGET_SLACK  # the step: off, or as noise


def test_gap_points_lie_a_quarter_of_the_way_to_the_neighbours_of_the_worst_predicted_stations():
    from app.geometry.traces import TracePolyline
    from app.probing.field_verify import GAP_FRACTION, gap_points

    line = TracePolyline.from_points(np.column_stack([np.linspace(0, 20, 41), np.full(41, 5.0), np.zeros(41)]))
    trace = np.array([0, 0, 0, 0, 0, -1])
    s = np.array([0.0, 5.0, 10.0, 10.2, 20.0, np.nan])      # 10.2: a re-touch of the station at 10 (same spot)
    z = np.array([0.1, 0.5, -3.0, 0.2, 2.0, 9.0])            # off-trace station (z 9) has no gap along a trace
    points = gap_points([line], trace, s, z, stations=2)       # worst: s 10 (both sides), s 20 (the end: one side)
    assert GAP_FRACTION == 0.25
    assert np.allclose(points.s, [8.75, 12.5, 17.55])
    assert np.allclose(points.sites.xy, [[8.75, 5.0], [12.5, 5.0], [17.55, 5.0]])
    # a spot touched again is one surprise: its re-touch (s 10.2, z next worst) gives way to s 20
    z_spot = np.array([0.1, 0.5, -3.0, 2.5, 2.0, 9.0])
    assert np.allclose(gap_points([line], trace, s, z_spot, stations=2).s, [8.75, 12.5, 17.55])
    assert (points.trace == 0).all() and len(gap_points([line], trace, s, z, stations=0)) == 0


def test_gap_points_also_lie_beside_the_station_the_others_predict_worst_in_mm():
    """A station at a trace's end is predicted from one side only: its leave-one-out sd is
    large, so a step at the station itself leaves its z small while its residual in mm is
    the largest: the gap beside it is verified too."""
    from app.geometry.traces import TracePolyline
    from app.probing.field_verify import gap_points

    line = TracePolyline.from_points(np.column_stack([np.linspace(0, 20, 41), np.full(41, 5.0), np.zeros(41)]))
    trace = np.zeros(5, dtype=int)
    s = np.array([0.0, 5.0, 10.0, 15.0, 20.0])
    z = np.array([0.5, -3.0, 0.1, 0.2, 0.9])
    residual = np.array([0.004, 0.003, 0.001, 0.002, 0.012])  # the end at s 20: small z, largest in mm
    assert np.allclose(gap_points([line], trace, s, z, stations=1).s, [3.75, 6.25])
    assert np.allclose(gap_points([line], trace, s, z, residual, stations=1, by_residual=1).s, [3.75, 6.25, 18.75])
    # the station already picked by its z is not picked again: the next worst in mm is
    assert np.allclose(gap_points([line], trace, s, z, residual * [1, 9, 1, 1, 1], stations=1, by_residual=1).s,
                       [3.75, 6.25, 18.75])


def test_sequential_verification_counts_the_gap_points_among_its_points(paths):
    """The gap points count among the ``count`` verification points: the least certain ones
    fill the rest, at least MIN_LEAST_CERTAIN, chosen as if the gap points were touched."""
    from app.probing.field_verify import MIN_LEAST_CERTAIN, gap_points, with_sequential_verification

    plan = plan_field(paths, DEFAULT)
    none = with_sequential_verification(replace_empty(plan), plan.sites, paths, DEFAULT.prior(), 5)
    assert none.count == 5 and none.verify_mask.all()                     # no surprise given: 5 least certain
    z = np.zeros(plan.count)
    z[np.flatnonzero(plan.trace >= 0)[[3, 10]]] = [4.0, -3.5]             # two surprising stations
    surprise = (plan.trace, plan.s_mm, z)
    gaps = gap_points(paths, plan.trace, plan.s_mm, z)
    assert len(gaps) >= 2
    for count in (2, 5, 8):
        with_gaps = with_sequential_verification(replace_empty(plan), plan.sites, paths, DEFAULT.prior(), count,
                                                 surprise)
        assert with_gaps.count == max(count, len(gaps) + min(count, MIN_LEAST_CERTAIN))
        assert np.allclose(with_gaps.xy[-len(gaps):], gaps.sites.xy)      # the gap points last
        least = with_gaps.xy[:-len(gaps)]
        assert not np.isin(least.round(6), gaps.sites.xy.round(6)).all(axis=1).any()


def replace_empty(plan):
    """``plan`` without stations (a sequential round that adds none)."""
    from dataclasses import replace
    return replace(plan, xy=plan.xy[:0], z=plan.z[:0], grad=plan.grad[:0], trace=plan.trace[:0],
                   s_mm=plan.s_mm[:0], order=plan.order[:0])


def test_a_chip_touched_again_does_not_shorten_the_learned_wavelength(paths):
    """The default plan on the 14 mm part, one touch on a 0.3 mm chip: learned from every touch
    the wavelength collapses; with the spot touched again twice (the chip gone) the chip is
    screened out before the fit and the wavelength is the clean touches' (within 20 % of 14 mm)."""
    from app.probing.deviation_prior import Sites
    from app.reconstruction.field_learning import learn_prior

    plan = plan_field(paths, DEFAULT)
    dz = toucher(1)(plan.xy)
    clean = learn_prior(DEFAULT.prior(), plan.sites, dz, plan.center).prior.wavelength_mm
    chipped = dz.copy()
    chipped[7] += 0.3
    blind = learn_prior(DEFAULT.prior(), plan.sites, chipped, plan.center, screen=False).prior.wavelength_mm
    assert blind < 0.7 * clean                                 # one bad touch drags the wavelength down
    spot = plan.xy[[7, 7]] + [[0.05, 0.0], [-0.05, 0.0]]
    sites = Sites(np.concatenate([plan.xy, spot]), np.concatenate([plan.sites.grad, plan.sites.grad[[7, 7]]]))
    learned = learn_prior(DEFAULT.prior(), sites, np.concatenate([chipped, fourteen(spot)]), plan.center)
    assert learned.screened == (7,)
    assert abs(learned.prior.wavelength_mm / 14.0 - 1) < 0.2 and abs(learned.prior.wavelength_mm / clean - 1) < 0.05


def test_the_bound_over_a_whole_trace_is_the_union_bound_over_its_independent_values():
    from scipy.stats import norm

    from app.reconstruction.field_trust import joint_coverage, simultaneous_bound

    sd = np.full(161, 0.001)                                  # 10 wavelengths sampled every lambda / 16: 20 values
    u = simultaneous_bound(sd, 1.0, 16.0, 3.0)
    assert u == pytest.approx(0.001 * norm.isf(norm.sf(3.0) / (161 / 8)), rel=1e-6)
    assert simultaneous_bound(np.array([0.001, 1e-6]), 1.0, 16.0, 3.0) == pytest.approx(0.003)  # one value: 3 sd
    assert joint_coverage(3.0, 1) == pytest.approx(3.0) and joint_coverage(3.0, 5) > 3.4


def test_a_point_is_worse_than_nominal_only_when_the_residual_is_more_than_the_noise():
    from app.reconstruction.field_trust import Verification

    v = Verification(np.zeros((3, 2)), np.array([0, 1, 2]), np.array([0.0005, 0.002, 0.004]),
                     np.array([-0.0005, -0.004, 0.003]), np.full(3, 0.0015), np.full(3, 0.005), 0.003)
    assert v.worse.tolist() == [False, True, False]          # noise-level disagreement near nominal is not "worse"
    assert Verification.from_arrays(v.arrays()).worse.tolist() == [False, True, False]


def test_a_round_refines_the_wavelength_step_by_step_and_plans_for_the_probes_noise():
    from app.probing.deviation_prior import DeviationPrior
    from app.reconstruction.field_sequential import pilot_params, round_params

    assert pilot_params(DEFAULT).deviation_wavelength_mm == 2 * DEFAULT.deviation_wavelength_mm
    aliased = round_params(DEFAULT, DeviationPrior(amplitude_mm=0.1, wavelength_mm=5.0, sigma_mm=0.001), 40.0)
    assert aliased.deviation_wavelength_mm == 20.0 and aliased.deviation_amplitude_mm == 0.1
    noisy = round_params(DEFAULT, DeviationPrior(amplitude_mm=0.1, wavelength_mm=30.0, sigma_mm=0.02), 20.0)
    assert noisy.deviation_wavelength_mm == 10.0 and noisy.probe_sigma_mm == DEFAULT.probe_sigma_mm
    resolved = round_params(DEFAULT, DeviationPrior(amplitude_mm=0.1, wavelength_mm=13.0, sigma_mm=0.0013), 20.0)
    assert resolved.deviation_wavelength_mm == 13.0 and resolved.probe_sigma_mm == DEFAULT.probe_sigma_mm


def test_a_runs_trace_bounds_factorise_the_bound_posterior_once_and_equal_each_trace_bound_alone(paths, monkeypatch):
    """Every trace of a run asks for the same posterior under the cautious prior: it is
    factorised once per fit, and each trace's bound is the one :func:`trace_bound` gives for a
    fresh copy of the fit (its own factorisation), to rounding: the run's traces are bounded
    in one batch, whose sums the vector units may order differently from one trace's (the
    corner's prior: on the ellipse each trace alone finds its own worst point)."""
    from dataclasses import replace

    from app.reconstruction import field_trust

    monkeypatch.setattr(field_trust, "HYPER_BOUND", "corner")
    plan = plan_field(paths, DEFAULT)
    dz = toucher(3)(plan.xy)
    check = checked_field(DEFAULT.prior(), plan.sites, np.zeros(plan.count), np.column_stack([plan.xy, dz]),
                          plan.center, plan.trace, plan.s_mm, np.zeros(plan.count, dtype=bool), DEFAULT.coverage,
                          DEFAULT.target_error_mm)
    assert field_trust.cautious_prior(check.fit.posterior.prior, check.learned) != check.fit.posterior.prior
    alone = [trace_bound(replace(check.fit), p, DEFAULT.coverage, check.learned, len(paths)) for p in paths]
    factorised = []
    real = field_trust.fit_posterior
    monkeypatch.setattr(field_trust, "fit_posterior", lambda *a, **k: factorised.append(1) or real(*a, **k))
    assert run_bounds(check, paths) == pytest.approx(alone, rel=1e-12, abs=0)
    assert len(factorised) == 1
    # a board job's trace bounds, batched: each trace's own (the trace count shares the confidence)
    assert field_trust.trace_bounds(check.fit, paths, DEFAULT.coverage, check.learned, len(paths)).tolist() \
        == pytest.approx(alone, rel=1e-12, abs=0)


def test_the_stations_check_given_the_callers_learning_is_the_check_that_learns_itself(paths):
    from app.reconstruction.field_learning import learn_prior
    from app.reconstruction.field_sequential import stations_check

    plan = plan_field(paths, DEFAULT)
    dz = toucher(5)(plan.xy)
    args = (DEFAULT.prior(), plan.sites, dz, plan.center, plan.trace, plan.s_mm, paths, DEFAULT.coverage,
            DEFAULT.target_error_mm)
    learned = learn_prior(DEFAULT.prior(), plan.sites, dz, plan.center)
    given, itself = stations_check(*args, learned=learned), stations_check(*args)
    assert given.learned == itself.learned and given.bound_mm == itself.bound_mm
    assert np.array_equal(given.fit.dz, itself.fit.dz) and given.fit.outliers == itself.fit.outliers


def test_the_run_bounds_batched_are_each_traces_bound_and_the_sd_the_dense_formula(paths, monkeypatch):
    """Every trace's bound from one batched solve (batches of 7 points, across the traces)
    is the bound of that trace alone, and the posterior sd is prior variance - k' K^-1 k
    with K^-1 from a dense solve (an independent reference)."""
    import app.reconstruction.field_trust as field_trust
    from app.probing.deviation_prior import fit_posterior, prior_covariance, prior_variance

    plan = plan_field(paths, PlanParams())
    posterior = fit_posterior(PlanParams().prior(), plan.sites, np.zeros(plan.count), plan.center)
    alone = [field_trust.posterior_trace_bounds(posterior, [p], 3.0, len(paths))[0] for p in paths]
    monkeypatch.setattr(field_trust, "SD_BATCH", 7)
    assert field_trust.posterior_trace_bounds(posterior, paths, 3.0) == pytest.approx(alone, rel=1e-9)
    sites = path_sites(paths[0], np.linspace(0.0, paths[0].length_mm, 9))
    prior = posterior.prior
    k = prior_covariance(prior, plan.sites, plan.sites, plan.center)
    jitter = max(prior.sigma_mm ** 2, 1e-10 * prior.rms_mm ** 2)
    kq = prior_covariance(prior, plan.sites, sites, plan.center)
    dense = prior_variance(prior, sites, plan.center) - np.sum(kq * np.linalg.solve(k + jitter * np.eye(len(k)), kq),
                                                               axis=0)
    assert posterior.sd(sites) == pytest.approx(np.sqrt(np.maximum(dense, 0.0)), rel=1e-6, abs=1e-9)


def test_the_batched_bounds_are_each_traces_root_and_do_not_depend_on_the_batch():
    """simultaneous_bounds solves T traces' equations together: each is the root brentq finds
    for that trace alone (an independent solver, to its tolerance), the same number, bit for
    bit, as the trace solved alone."""
    from scipy.optimize import brentq
    from scipy.special import ndtr

    from app.reconstruction.field_trust import simultaneous_bound, simultaneous_bounds

    rng = np.random.default_rng(4)
    lengths = rng.integers(1, 60, 200)
    edges = np.concatenate([[0], np.cumsum(lengths)])
    sd = rng.uniform(0.0005, 0.002, edges[-1]) * np.repeat(rng.uniform(0.2, 3.0, len(lengths)), lengths)
    steps = rng.uniform(0.5, 1.5, len(lengths))
    together = simultaneous_bounds(sd, edges, steps, 15.0, 3.0, len(lengths))
    alpha = 2.0 * ndtr(-3.0) / len(lengths)
    for t, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        w = min(1.0, 2.0 * steps[t] / 15.0)
        lo = 3.0 * sd[a:b].max()
        def excess(u: float, a: int = a, b: int = b, w: float = w) -> float:
            return w * float(np.sum(2.0 * ndtr(-u / sd[a:b]))) - alpha
        root = lo if excess(lo) <= 0 else brentq(excess, lo, 64 * lo, xtol=1e-14, rtol=1e-14)
        assert together[t] == pytest.approx(root, rel=1e-12)
        assert together[t] == simultaneous_bound(sd[a:b], steps[t], 15.0, 3.0, len(lengths))


def test_the_kept_bound_sites_are_the_fresh_ones_at_every_wavelength(paths):
    """A trace's bound sites kept at its last count asked give the bounds the fresh sites give,
    bit for bit, at wavelengths asked in turn (most traces keep their count, some do not)."""
    import app.reconstruction.field_trust as field_trust
    from app.probing.deviation_prior import DeviationPrior, fit_posterior

    plan = plan_field(paths, PlanParams())
    bounds = []
    for wavelength in (15.0, 15.3, 15.0, 30.0, 15.3):
        posterior = fit_posterior(DeviationPrior(0.15, wavelength), plan.sites, np.zeros(plan.count), plan.center)
        kept = field_trust.posterior_trace_bounds(posterior, paths, 3.0)
        field_trust._BOUND_SITES.clear()
        fresh = field_trust.posterior_trace_bounds(posterior, paths, 3.0)
        assert kept == fresh
        bounds.append(kept)
    assert bounds[0] == bounds[2] and bounds[1] == bounds[4] and bounds[0] != bounds[1]


def test_the_ellipse_bound_takes_the_largest_over_its_points_and_the_corner_without_a_correlation(paths, monkeypatch):
    """HYPER_BOUND "ellipse": the same bounds again without a factorisation; each trace's bound
    is at least its bound under the learned prior itself (the estimate is one of the points)
    and is that bound where the hyperparameters' sd are zero; a learning without a correlation
    (a cached one) is taken at the corner; the
    run's largest trace's own bound is the run's bound (a trace alone finds the ellipse's worst
    point by its own bound, the run by its largest); the learning's correlation of log A and log
    lambda is positive (a longer wavelength with a larger amplitude explains the same touches)."""
    from dataclasses import replace

    from app.reconstruction import field_trust
    from app.reconstruction.field_trust import posterior_trace_bounds, posterior_under

    plan = plan_field(paths, DEFAULT)
    dz = toucher(3)(plan.xy)
    check = checked_field(DEFAULT.prior(), plan.sites, np.zeros(plan.count), np.column_stack([plan.xy, dz]),
                          plan.center, plan.trace, plan.s_mm, np.zeros(plan.count, dtype=bool), DEFAULT.coverage,
                          DEFAULT.target_error_mm)
    assert check.learned is not None and 0.0 < check.learned["amplitude_wavelength_correlation"] < 1.0
    monkeypatch.setattr(field_trust, "HYPER_BOUND", "corner")
    corner = run_bounds(check, paths)
    at_estimate = np.array(posterior_trace_bounds(check.fit.posterior, paths, DEFAULT.coverage))
    monkeypatch.setattr(field_trust, "HYPER_BOUND", "ellipse")
    ellipse = np.array(run_bounds(check, paths))
    factorised = []
    real = field_trust.fit_posterior
    monkeypatch.setattr(field_trust, "fit_posterior", lambda *a, **k: factorised.append(1) or real(*a, **k))
    assert np.array_equal(run_bounds(check, paths), ellipse) and not factorised   # each point's posterior kept
    assert (ellipse >= at_estimate).all() and ellipse.max() > at_estimate.max()
    alone = np.array([trace_bound(check.fit, p, DEFAULT.coverage, check.learned, len(paths)) for p in paths])
    largest = int(np.argmax(ellipse))
    assert alone[largest] == pytest.approx(ellipse[largest], rel=1e-12) and (alone >= at_estimate).all()
    assert np.array_equal(field_trust.trace_bounds(check.fit, paths, DEFAULT.coverage, check.learned, len(paths)),
                          alone)   # each trace's own worst point, not the run's
    exact = {**check.learned, **{k: {**check.learned[k], "relative_sd": 0.0}
                                 for k in ("amplitude_mm", "wavelength_mm")}}
    assert np.array_equal(run_bounds(replace(check, learned=exact), paths), at_estimate)
    cached = {k: v for k, v in check.learned.items() if k != "amplitude_wavelength_correlation"}
    assert run_bounds(replace(check, learned=cached), paths) == corner
    with pytest.raises(ValueError):
        field_trust.cautious_bounds(lambda p: np.array(posterior_trace_bounds(posterior_under(check.fit, p), paths,
                                                                              DEFAULT.coverage)),
                                    check.fit.posterior.prior, check.learned, "box")
