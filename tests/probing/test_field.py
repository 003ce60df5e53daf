"""The field planner: rank-one updates, the automatic count, the region's degrees of
freedom, and one fitted field against the per-trace joint (kriging + context) result."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import solve_triangular

from app.probing.deviation_prior import Sites, prior_covariance, prior_variance
from app.probing.field import GreedyField, PlanError, plan_field
from app.probing.field_posterior import eliminate_redundant, posterior_parts, posterior_sd
from app.probing.field_region import covered_area_mm2, field_region, sample_traces
from app.probing.selection import PlanParams, plan_probes
from app.reconstruction.field import fit_field, trace_reconstruction
from app.reconstruction.reconstruct import ReconstructParams, reconstruct
from app.reference.boards import as_made_board, board_path, board_traces, s1_part
from app.reference.s1 import nominal_path, s1_traces

PARAMS = PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)
PRIOR = PARAMS.prior()


@pytest.fixture(scope="module")
def nine():
    return [nominal_path(t, 0.05) for t in s1_traces()]


def test_rank_one_rows_equal_a_fresh_cholesky_factorisation(nine):
    region = field_region(nine[:4], 15.0)
    sites = region.targets.sites
    greedy = GreedyField(PRIOR, sites, region.center)
    rng = np.random.default_rng(3)
    chosen = rng.choice(len(sites.xy), 25, replace=False)
    for j in chosen:
        greedy.add(int(j))
    stations = sites.take(chosen)
    k = prior_covariance(PRIOR, stations, stations, region.center) + greedy.jitter * np.eye(len(chosen))
    rows = solve_triangular(np.linalg.cholesky(k), prior_covariance(PRIOR, stations, sites, region.center),
                            lower=True)
    assert np.allclose(greedy.rows[:len(chosen)], rows, atol=1e-12, rtol=1e-9)
    fresh = posterior_sd(PRIOR, stations, sites, region.center) ** 2
    assert np.allclose(greedy.var, fresh, atol=1e-14)
    assert np.allclose(greedy.prior_var, prior_variance(PRIOR, sites, region.center))


def test_the_greedys_room_for_more_stations_is_at_most_half_again_and_extending_keeps_none(nine):
    region = field_region(nine[:4], 15.0)
    sites = region.targets.sites
    greedy = GreedyField(PRIOR, sites, region.center)
    for n, j in enumerate(np.random.default_rng(5).choice(len(sites.xy), 60, replace=False), start=1):
        greedy.add(int(j))
        assert n <= len(greedy.rows) <= max(16, n + n // 2 + 1) and greedy.low.shape == (len(greedy.rows),) * 2
    extra = region.samples.sites.take(np.arange(10))
    greedy.extend(extra)
    assert greedy.rows.shape == (60, len(sites.xy) + 10)   # the rows in use, one column per site
    stations = greedy.sites.take(np.array(greedy.chosen))
    k = prior_covariance(PRIOR, stations, stations, region.center) + greedy.jitter * np.eye(60)
    fresh = solve_triangular(np.linalg.cholesky(k), prior_covariance(PRIOR, stations, greedy.sites, region.center),
                             lower=True)
    assert np.allclose(greedy.rows, fresh, atol=1e-12, rtol=1e-9)
    greedy.add(int(len(sites.xy) + 3))   # adding after the extension makes room again
    assert len(greedy.chosen) == 61 and 61 <= len(greedy.rows) <= 91


def test_stations_added_at_once_are_the_stations_added_one_at_a_time(nine):
    # from no station and from some, a re-touch (the same site twice) among them; R, L and the
    # variance to rounding, against the one-at-a-time factor and a fresh Cholesky factorisation
    region = field_region(nine[:4], 15.0)
    sites = region.targets.sites
    js = np.random.default_rng(4).choice(len(sites.xy), 70, replace=False)
    js[9] = js[2]
    one, block = GreedyField(PRIOR, sites, region.center), GreedyField(PRIOR, sites, region.center)
    for j in js:
        one.add(int(j))
    block.add_many(js[:30])
    block.add_many(js[30:])
    block.add_many(np.zeros(0, dtype=int))
    assert block.chosen == one.chosen and len(block.rows) == 70 and block.low.shape == (70, 70)
    assert np.allclose(block.rows, one.rows[:70], atol=1e-12, rtol=1e-9)
    assert np.allclose(block.low, one.low[:70, :70], atol=1e-12, rtol=1e-9)
    assert np.allclose(block.var, one.var, atol=1e-14)
    stations = sites.take(js)
    k = prior_covariance(PRIOR, stations, stations, region.center) + block.jitter * np.eye(70)
    assert np.allclose(block.low @ block.low.T, k, atol=1e-12, rtol=1e-9)
    block.add(int(js[40]) + 1)   # one more after: room made as after the one-at-a-time adds
    assert len(block.chosen) == 71 and 71 <= len(block.rows) <= 106


def test_the_automatic_count_meets_the_target_and_no_station_can_be_dropped(nine):
    plan = plan_field(nine, PARAMS)
    target_sd = PARAMS.target_error_mm / PARAMS.coverage
    samples = sample_traces(nine, 15.0 / 16).sites
    full = posterior_sd(PRIOR, plan.sites, samples, plan.center)  # a fresh factorisation
    assert full.max() <= target_sd * (1 + 1e-9) and math.isclose(full.max(), plan.max_sd_mm, rel_tol=1e-7)
    # backward elimination left a minimal design: without any one station some point fails
    for j in range(plan.count):
        without = plan.sites.take(np.delete(np.arange(plan.count), j))
        assert posterior_sd(PRIOR, without, samples, plan.center).max() > target_sd, j
    # every station lies on its trace at its arc length
    for xy, t, s in zip(plan.xy, plan.trace, plan.s_mm):
        assert np.allclose(nine[t].at(np.array([s]))[0, :2], xy, atol=1e-12)
    assert np.all(plan.trace_sd_mm <= target_sd * (1 + 1e-9))
    # fewer touches than planning each trace on its own for the same target
    assert plan.count < sum(plan_probes(p, "kriging", PARAMS).count for p in nine)
    assert plan_field(nine, PlanParams(count=20, **{k: getattr(PARAMS, k) for k in (
        "deviation_amplitude_mm", "deviation_wavelength_mm")})).count == 20


def test_elimination_downdates_equal_a_fresh_posterior_and_drop_only_what_keeps_the_target(nine):
    region = field_region(nine[:4], 15.0)
    sites = region.targets.sites
    rng = np.random.default_rng(5)
    stations = sites.take(rng.choice(len(sites.xy), 60, replace=False))  # far more than needed
    where = region.samples.sites
    start = posterior_parts(PRIOR, stations, where, region.center)
    target_var = (start.var.max() * 1.5)
    kept = eliminate_redundant(start, target_var, 4)
    assert 4 <= len(kept.keep) < 60
    fresh = posterior_sd(PRIOR, stations.take(kept.keep), where, region.center) ** 2
    assert np.allclose(kept.var, fresh, atol=1e-13) and fresh.max() <= target_var
    jitter = PRIOR.sigma_mm ** 2
    k = prior_covariance(PRIOR, stations.take(kept.keep), stations.take(kept.keep), region.center)
    assert np.allclose(kept.precision, np.linalg.inv(k + jitter * np.eye(len(k))), rtol=1e-6,
                       atol=1e-6 * abs(kept.precision).max())


def test_the_design_depends_on_the_region_not_on_the_number_of_traces(nine):
    once = plan_field(nine, PARAMS)
    twice = plan_field(nine + nine, PARAMS)  # every trace listed twice: the same region
    assert twice.count == once.count
    assert np.allclose(twice.xy, once.xy) and math.isclose(twice.dof, once.dof)


def test_covered_area_and_degrees_of_freedom_of_one_straight_trace():
    path = board_path(s1_part(), {"type": "line", "start": [10.0, 10.0], "end": [40.0, 10.0]}, 0.05)
    samples = sample_traces([path], 15.0 / 16)
    reach = 15.0 / 4
    exact = 30.0 * 2 * reach + math.pi * reach ** 2  # a stadium
    assert covered_area_mm2(samples.sites.xy, 15.0) == pytest.approx(exact, rel=0.03)
    region = field_region([path], 15.0)
    assert region.nyquist_dof == pytest.approx(region.area_mm2 / 7.5 ** 2 + 6)


def test_bad_input_is_refused_naming_the_field(nine):
    with pytest.raises(PlanError) as err:
        plan_field(nine, PARAMS, stations="everywhere")
    assert err.value.field == "stations"
    with pytest.raises(PlanError) as err:
        plan_field(nine, PARAMS, stations="anywhere_on_top")
    assert err.value.field == "stations"
    with pytest.raises(PlanError) as err:
        plan_field([], PARAMS)
    assert err.value.field == "traces"


def test_one_field_equals_the_per_trace_joint_kriging_reconstruction():
    part = s1_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 6, seed=2)]
    plan = plan_field(paths, PlanParams(count=24, deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0))
    truth = as_made_board(part, seed=7)
    measured = plan.points.copy()
    measured[:, 2] = truth.true_height(plan.xy)
    fit = fit_field(PRIOR, plan.sites, plan.z, measured, plan.center, plan.trace, plan.s_mm)
    assert fit.outliers == ()
    params = ReconstructParams(prior=PRIOR)
    own = [measured[plan.trace == i] for i in range(len(paths))]
    for i, path in enumerate(paths):
        if len(own[i]) < 4:
            continue  # the joint reconstruction needs 4 of the trace's own points
        field = trace_reconstruction(fit, path, i, params)
        joint = reconstruct(path, own[i], "kriging", sigma_mm=PRIOR.sigma_mm, params=params,
                            context=[(paths[j], own[j]) for j in range(len(paths)) if j != i and len(own[j])])
        s = np.linspace(0.0, path.length_mm, 50)
        assert np.allclose(field.height_at_s(s), joint.height_at_s(s), atol=2e-6)


def test_an_outlier_station_is_dropped_and_the_field_holds():
    part = s1_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 9)]
    plan = plan_field(paths, PARAMS)
    truth = as_made_board(part, seed=8)
    measured = plan.points.copy()
    measured[:, 2] = truth.true_height(plan.xy)
    clean = fit_field(PRIOR, plan.sites, plan.z, measured, plan.center, plan.trace, plan.s_mm)
    spiked = measured.copy()
    spiked[17, 2] += 0.2  # a chip under the probe
    fit = fit_field(PRIOR, plan.sites, plan.z, spiked, plan.center, plan.trace, plan.s_mm)
    assert fit.outliers == (17,)
    xy = np.concatenate([p.points[::20, :2] for p in paths])
    sites = Sites(xy, part.gradient(xy))
    assert np.abs(fit.deviation(sites) - clean.deviation(sites)).max() < 0.005
