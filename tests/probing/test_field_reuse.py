"""A round's shared plan state (:class:`app.probing.field_reuse.PlanReuse`): the plans made
with it are the cold plans to the bit, whatever order the targets come in."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from app.probing.deviation_prior import jinc_kernel, prior_covariance
from app.probing.field import FieldPlan, GreedyField, plan_field
from app.probing.field_region import field_region
from app.probing.field_reuse import PlanReuse
from app.probing.selection import PlanParams
from app.reference.s1 import nominal_path, s1_traces

PARAMS = PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)


@pytest.fixture(scope="module")
def nine():
    return [nominal_path(t, 0.05) for t in s1_traces()]


def _same(a: FieldPlan, b: FieldPlan) -> None:
    for name in ("xy", "z", "grad", "trace", "s_mm", "center", "trace_sd_mm", "order"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert a.max_sd_mm == b.max_sd_mm


def test_a_rounds_plans_with_the_reuse_are_the_cold_plans_to_the_bit(nine, monkeypatch):
    pilot = plan_field(nine, replace(PARAMS, deviation_wavelength_mm=30.0))
    fixed = pilot.sites
    reuse = PlanReuse()
    added: list[int] = []
    add = GreedyField.add
    monkeypatch.setattr(GreedyField, "add", lambda self, j: added.append(j) or add(self, j))
    targets = [0.005, 0.0025, 0.004, 0.0025, 0.0032]   # looser and tighter, one asked twice
    plans = [plan_field(nine, replace(PARAMS, target_error_mm=t), fixed=fixed, reuse=reuse) for t in targets]
    warm = len(added)
    assert len({p.count for p in plans}) > 2   # the targets buy different designs
    for t, plan in zip(targets, plans):
        _same(plan, plan_field(nine, replace(PARAMS, target_error_mm=t), fixed=fixed))
    assert warm < (len(added) - warm) / 2   # the kept states spared most of the greedy's steps
    # another prior (a new key) beside the kept one
    other = replace(PARAMS, deviation_amplitude_mm=0.2)
    _same(plan_field(nine, other, fixed=fixed, reuse=reuse), plan_field(nine, other, fixed=fixed))


def test_a_rounds_kept_states_hold_their_rows_once(nine):
    fixed = plan_field(nine, replace(PARAMS, deviation_wavelength_mm=30.0)).sites
    reuse = PlanReuse()
    for t in [0.0032, 0.005, 0.0025, 0.004]:   # the longest state comes neither first nor last
        plan_field(nine, replace(PARAMS, target_error_mm=t), fixed=fixed, reuse=reuse)
    (stops,) = reuse._stops.values()
    states = list(stops.values())
    assert len({len(g.chosen) for g in states}) > 2
    longest = max(states, key=lambda g: len(g.chosen))
    for g in states:   # the first rows of the longest, no room for more: one R in memory
        assert len(g.rows) == max(len(g.chosen), 1)
        assert np.shares_memory(g.rows, longest.rows)
        assert np.array_equal(g.rows, longest.rows[:len(g.rows)])


def test_a_spent_kernel_gives_the_same_covariance(nine):
    region = field_region(nine, 15.0)
    prior = PARAMS.prior()
    stations, where = region.targets.sites.take(np.arange(0, 40, 3)), region.samples.sites
    fresh = prior_covariance(prior, stations, where, region.center)
    unit = jinc_kernel(stations.xy, where.xy, prior.wavelength_mm)
    kept = unit.copy()
    assert np.array_equal(prior_covariance(prior, stations, where, region.center, unit), fresh)
    assert np.array_equal(unit, kept)   # not spent: left as it was
    spent = prior_covariance(prior, stations, where, region.center, unit, spend_jinc=True)
    assert spent is unit and np.array_equal(spent, fresh)


def test_the_kept_kernel_rows_are_the_fresh_kernel(nine):
    region = field_region(nine, 15.0)
    prior = PARAMS.prior()
    where = region.samples.sites
    rng = np.random.default_rng(4)
    pool = region.targets.sites
    reuse = PlanReuse()
    first = rng.choice(len(pool.xy), 30, replace=False)
    second = np.concatenate([first[5:20], rng.choice(len(pool.xy), 10, replace=False), first[:1]])  # kept, new, twice
    for idx in (first, second, first[:1]):
        stations = pool.take(idx)
        got = reuse.jinc(stations.xy, where, prior.wavelength_mm)
        fresh = jinc_kernel(stations.xy, where.xy, prior.wavelength_mm)
        assert got.shape == fresh.shape
        assert np.array_equal(got.block(0, len(where.xy)), fresh)
        assert np.array_equal(got.block(3, 40), fresh[:, 3:40]) and got.block(3, 40).flags.c_contiguous
        assert np.array_equal(prior_covariance(prior, stations, where, region.center, got.block(0, len(where.xy))),
                              prior_covariance(prior, stations, where, region.center))
    assert reuse.jinc(np.zeros((0, 2)), where, prior.wavelength_mm).block(0, 5).shape == (0, 5)


def test_the_region_is_kept_per_wavelength(nine):
    reuse = PlanReuse()
    a = reuse.region(nine, 15.0, None)
    assert reuse.region(nine, 15.0, None) is a and reuse.region(nine, 16.0, None) is not a
    cold = field_region(nine, 16.0)
    assert np.array_equal(reuse.region(nine, 16.0, None).targets.sites.xy, cold.targets.sites.xy)
