"""The exchange refinement of the field planner: its rank-one bookkeeping against fresh
factorisations, and the plans it ends with (target met on every trace sample, minimal,
never more stations than without it, deterministic, fewer stations on S1's boards)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import app.probing.field_exchange as fx
from app.probing.deviation_prior import Sites
from app.probing.field import plan_field
from app.probing.field_posterior import posterior_parts, posterior_sd
from app.probing.field_region import field_region, sample_traces
from app.probing.selection import PlanParams
from app.reference.boards import board_path, board_traces, s1_part
from app.reference.s1 import nominal_path, s1_traces

PARAMS = PlanParams(coverage=4.0, deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0, exchange=True)
PRIOR = PARAMS.prior()
TARGET_VAR = (PARAMS.target_error_mm / PARAMS.coverage) ** 2


@pytest.fixture(scope="module")
def nine():
    return [nominal_path(t, 0.05) for t in s1_traces()]


@pytest.fixture(scope="module")
def board81():
    part = s1_part()
    return [board_path(part, g, 0.05) for g in board_traces(part, 81)]


def _without_exchange(paths, monkeypatch):  # type: ignore[no-untyped-def]
    """The same plan with the exchange switched off (the default), and with no moves: equal."""
    off = plan_field(paths, replace(PARAMS, exchange=False))
    with monkeypatch.context() as m:
        m.setattr(fx, "TRIALS_PER_STATION", 0)
        assert plan_field(paths, PARAMS).count == off.count
    return off


def _fresh_weights(candidates: Sites, stations: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    parts = posterior_parts(PRIOR, candidates.take(stations), candidates, center)
    return parts.weights, parts.var


def _random_design(paths, seed: int, size: int):  # type: ignore[no-untyped-def]
    """(region, candidates, rng, start stations, their DesignPosterior) on four traces."""
    region = field_region(paths[:4], 15.0)
    cand = region.targets.sites
    rng = np.random.default_rng(seed)
    start = rng.choice(len(cand.xy), size, replace=False)
    return region, cand, rng, start, fx.DesignPosterior(PRIOR, region.center, cand, start)


def test_design_posterior_rank_one_updates_equal_a_fresh_factorisation(nine):
    region, cand, rng, start, post = _random_design(nine, 7, 40)
    stations = list(start)
    free = [int(i) for i in range(len(cand.xy)) if i not in set(stations)]
    for step in range(3 * fx.PENDING):        # enough to flush the pending updates several times
        if step % 3 == 2:
            j = int(free.pop(rng.integers(len(free))))
            post.add(j)
            stations.append(j)
        else:
            j = int(stations.pop(rng.integers(len(stations))))
            post.remove(j)
            free.append(j)
    assert sorted(post.slot_cand[post.used].tolist()) == sorted(stations)
    weights, var = _fresh_weights(cand, np.array(stations), region.center)
    assert np.allclose(post.var, var, atol=1e-12 * PRIOR.rms_mm ** 2)
    # the weights, row for row by station
    w = post.columns(np.arange(len(cand.xy)))
    order = [int(np.flatnonzero(post.slot_cand == s)[0]) for s in stations]
    assert np.allclose(w[order], weights, atol=1e-8)
    assert np.allclose(np.delete(w, order, axis=0), 0.0, atol=1e-12)


def test_a_trial_posterior_equals_the_design_after_the_same_moves(nine):
    region, cand, rng, start, post = _random_design(nine, 11, 50)
    local = np.arange(0, len(cand.xy), 2)
    slots = post.used[:6]
    trial = fx._Trial(post, local, slots)
    gone = [int(post.slot_cand[s]) for s in slots[:3]]
    for s in gone:
        trial.remove(s)
    new_u = [int(u) for u in local[:40:13] if int(u) not in set(start)][:2]
    for u in new_u:
        trial.add(int(np.flatnonzero(local == u)[0]))
    trial.remove(int(post.slot_cand[slots[4]]))
    stations = sorted(set(start.tolist()) - set(gone) - {int(post.slot_cand[slots[4]])} | set(new_u))
    _, var = _fresh_weights(cand, np.array(stations), region.center)
    assert np.allclose(trial.var, var[local], atol=1e-12 * PRIOR.rms_mm ** 2)
    u = 5
    fresh_col = posterior_parts(PRIOR, cand.take(np.array(stations)), cand.take(local), region.center)
    k_uu = fresh_col.var[u]
    assert np.isclose(trial.column(u)[u], k_uu, atol=1e-12 * PRIOR.rms_mm ** 2)


def _check_plan(plan, paths) -> None:  # type: ignore[no-untyped-def]
    samples = sample_traces(paths, 15.0 / 16).sites
    target_sd = PARAMS.target_error_mm / PARAMS.coverage
    sd = posterior_sd(PRIOR, plan.sites, samples, plan.center)      # a fresh factorisation
    assert sd.max() <= target_sd * (1 + 1e-9)
    assert np.isclose(sd.max(), plan.max_sd_mm, rtol=1e-7)
    # minimal: without any one station some sample fails (exact removal formula of the posterior)
    parts = posterior_parts(PRIOR, plan.sites, samples, plan.center)
    worst = (parts.weights ** 2 / np.diag(parts.precision)[:, None] + parts.var[None]).max(axis=1)
    assert np.all(worst > TARGET_VAR)
    j = int(np.argmin(worst))
    without = plan.sites.take(np.delete(np.arange(plan.count), j))
    assert posterior_sd(PRIOR, without, samples, plan.center).max() > target_sd
    # every on-trace station lies on its trace at its arc length
    for xy, t, s in zip(plan.xy, plan.trace, plan.s_mm):
        assert t >= 0 and np.allclose(paths[t].at(np.array([s]))[0, :2], xy, atol=1e-12)


def test_exchange_on_the_nine_s1_traces_meets_the_target_with_fewer_stations(nine, monkeypatch):
    base = _without_exchange(nine, monkeypatch)
    plan = plan_field(nine, PARAMS)
    _check_plan(plan, nine)
    assert plan.count <= base.count - 3, (plan.count, base.count)          # measured 66 -> 63
    again = plan_field(nine, PARAMS)
    assert np.array_equal(again.xy, plan.xy) and np.array_equal(again.s_mm, plan.s_mm)


def test_exchange_on_an_81_trace_s1_board_saves_at_least_5_percent(board81, monkeypatch):
    base = _without_exchange(board81, monkeypatch)
    plan = plan_field(board81, PARAMS)
    _check_plan(plan, board81)
    assert plan.count <= 0.95 * base.count, (plan.count, base.count)       # measured 86 -> 78


def test_exchange_never_adds_stations_and_keeps_a_given_count(nine, monkeypatch):
    for n in (2, 5):
        paths = nine[:n]
        assert plan_field(paths, PARAMS).count <= _without_exchange(paths, monkeypatch).count
    given = PlanParams(count=30, **{k: getattr(PARAMS, k) for k in (
        "coverage", "deviation_amplitude_mm", "deviation_wavelength_mm")})
    assert plan_field(nine, given).count == 30


def test_repair_adds_stations_until_every_point_meets_the_target(nine):
    region = field_region(nine[:3], 15.0)
    where = region.samples.sites
    plan = plan_field(nine[:3], PARAMS)
    stations = plan.sites.take(np.arange(0, plan.count, 2))          # half the stations: far over
    parts = posterior_parts(PRIOR, stations, where, region.center)
    assert parts.var.max() > TARGET_VAR
    added, precision, weights, var = fx.repair_stations(PRIOR, region.center, stations, where, parts.precision,
                                                        parts.weights, parts.var, TARGET_VAR)
    assert var.max() <= TARGET_VAR and 0 < len(added) < len(where.xy)
    both = Sites(np.concatenate([stations.xy, where.xy[added]]), np.concatenate([stations.grad, where.grad[added]]))
    fresh = posterior_parts(PRIOR, both, where, region.center)
    assert np.allclose(var, fresh.var, atol=1e-12 * PRIOR.rms_mm ** 2)
    assert np.allclose(precision, fresh.precision, rtol=1e-6, atol=1e-6 * np.abs(fresh.precision).max())
    assert np.allclose(weights, fresh.weights, atol=1e-8)


def test_exchange_with_free_stations_anywhere_on_top(monkeypatch):
    from app.probing.field_top import mesh_top_sampler

    part = s1_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 9)]
    top = mesh_top_sampler(part.mesh())
    with monkeypatch.context() as m:
        m.setattr(fx, "TRIALS_PER_STATION", 0)
        base = plan_field(paths, PARAMS, "anywhere_on_top", top)
    plan = plan_field(paths, PARAMS, "anywhere_on_top", top)
    assert plan.count < base.count
    samples = sample_traces(paths, 15.0 / 16).sites
    assert posterior_sd(PRIOR, plan.sites, samples, plan.center).max() <= PARAMS.target_error_mm / PARAMS.coverage * (
        1 + 1e-9)
    free = plan.trace < 0
    assert np.all(np.isnan(plan.s_mm[free])) and np.all(np.isfinite(plan.s_mm[~free]))
    for xy, t, s in zip(plan.xy[~free], plan.trace[~free], plan.s_mm[~free]):
        assert np.allclose(paths[t].at(np.array([s]))[0, :2], xy, atol=1e-12)
