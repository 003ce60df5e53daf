"""The field planner's fresh posterior in column blocks: the same numbers whatever the block,
the kriging weights kept only when asked for, and its memory that of its result."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import app.probing.field as field
from app.probing.deviation_prior import Sites, prior_covariance, prior_variance
from app.probing.field import plan_field
from app.probing.field_posterior import eliminate_redundant, posterior_parts
from app.probing.field_region import field_region
from app.probing.selection import PlanParams
from app.reference.s1 import nominal_path, s1_traces

PARAMS = PlanParams(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)
PRIOR = PARAMS.prior()


@pytest.fixture(scope="module")
def board():
    """(stations (60,), samples (N,), center) on the reference part's traces, sampled for a
    2 mm wavelength (N ~ 2,000: several blocks)."""
    region = field_region([nominal_path(t, 0.05) for t in s1_traces()], 2.0)
    sites = region.targets.sites
    stations = sites.take(np.random.default_rng(5).choice(len(sites.xy), 60, replace=False))
    return stations, region.samples.sites, region.center


BLOCK = 256  # columns: the samples make several blocks


def test_the_posterior_is_the_same_in_any_blocks_and_equals_a_direct_solve(board):
    stations, where, center = board
    assert len(where.xy) > 6 * BLOCK
    whole = posterior_parts(PRIOR, stations, where, center, block=len(where.xy))
    small = posterior_parts(PRIOR, stations, where, center, block=BLOCK)
    assert small.weights is not None and whole.weights is not None
    scale = prior_variance(PRIOR, where, center).max()  # the variance is the prior's less what the stations explain
    assert np.allclose(small.var, whole.var, rtol=0, atol=1e-12 * scale)
    assert np.allclose(small.weights, whole.weights, rtol=1e-12, atol=1e-12 * abs(whole.weights).max())
    k = prior_covariance(PRIOR, stations, stations, center) + PRIOR.sigma_mm ** 2 * np.eye(len(stations.xy))
    cross = prior_covariance(PRIOR, stations, where, center)
    direct = prior_variance(PRIOR, where, center) - np.einsum("ij,ij->j", cross, np.linalg.solve(k, cross))
    assert np.allclose(whole.var, np.maximum(direct, 0.0), rtol=0, atol=1e-9 * scale)


def test_without_weights_the_same_variance_and_no_n_by_n_array(board):
    stations, where, center = board
    kept = posterior_parts(PRIOR, stations, where, center, block=BLOCK)
    tracemalloc.start()
    try:
        bare = posterior_parts(PRIOR, stations, where, center, weights=False, block=BLOCK)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert bare.weights is None and np.array_equal(bare.var, kept.var)
    assert np.array_equal(bare.precision, kept.precision)
    n, count = len(stations.xy), len(where.xy)
    assert count > 6 * BLOCK
    assert peak < n * count * 8  # less than the (n, N) weights it no longer holds
    with pytest.raises(ValueError, match="kriging weights"):
        eliminate_redundant(bare, float(bare.var.max()), 4)


def test_a_round_with_touched_stations_keeps_no_weights(monkeypatch):
    """A sequential round's design (stations already touched) is never eliminated: its fresh
    posteriors keep only the variance; the first design (none touched) keeps the weights."""
    asked: list[bool] = []

    def spy(*args, weights=True, **kwargs):  # type: ignore[no-untyped-def]
        asked.append(weights)
        return posterior_parts(*args, weights=weights, **kwargs)

    monkeypatch.setattr(field, "posterior_parts", spy)
    paths = [nominal_path(t, 0.05) for t in s1_traces()][:4]
    first = plan_field(paths, PARAMS)
    assert asked and asked[0] is True
    asked.clear()
    touched = Sites(first.xy[: first.count // 2], first.grad[: first.count // 2])
    plan_field(paths, PARAMS, fixed=touched)
    assert asked and not any(asked)
