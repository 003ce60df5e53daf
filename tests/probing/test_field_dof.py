"""The field's degrees of freedom at the target: the Karhunen-Loeve truncation dimension.

Checked against what it claims: the mode variances are the prior's (they sum to its mean
variance over the region), no noise-free design of dof - 1 stations brings the mean
posterior variance to the target, analytic cases, and the grid's convergence."""

from __future__ import annotations

import math
import pickle
from dataclasses import replace

import numpy as np
import pytest

from app.probing import field_dof
from app.probing.deviation_prior import DeviationPrior, Sites, prior_covariance, prior_variance
from app.probing.field import plan_field
from app.probing.field_dof import mode_variances, region_grid, truncation_dof
from app.probing.field_region import field_region
from app.probing.selection import PlanParams
from app.reference.boards import board_path, board_traces, s1_part

PARAMS = PlanParams(coverage=4.0, deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)
PRIOR = PARAMS.prior()
TARGET_SD = PARAMS.target_error_mm / PARAMS.coverage


@pytest.fixture(scope="module")
def board():
    part = s1_part()
    return field_region([board_path(part, g, 0.05) for g in board_traces(part, 81)], 15.0)


def grid_sites(region) -> Sites:
    xy, _, nearest, _ = region_grid(region.samples, 15.0)
    return Sites(xy, region.samples.sites.grad[nearest])


def test_mode_variances_are_the_priors_over_the_region(board):
    v = mode_variances(PRIOR, board.samples, board.center)
    nodes = grid_sites(board)
    assert len(v) == len(nodes.xy)
    assert np.all(np.diff(v) <= 1e-15)                       # largest first
    assert v.sum() == pytest.approx(prior_variance(PRIOR, nodes, board.center).mean(), rel=1e-9)


def test_no_noise_free_design_of_dof_minus_one_stations_reaches_the_target_on_average(board):
    v = mode_variances(PRIOR, board.samples, board.center)
    dof = truncation_dof(v, TARGET_SD)
    assert v[dof:].sum() <= TARGET_SD ** 2 < v[dof - 1:].sum()
    nodes = grid_sites(board)
    k = prior_covariance(PRIOR, nodes, nodes, board.center)
    # the best greedy design for the MEAN variance, on the grid itself, noise-free
    cov = k.copy()
    chosen = []
    for _ in range(dof - 1):
        gain = np.sum(cov * cov, axis=0) / np.maximum(np.diag(cov), 1e-30)
        j = int(np.argmax(gain))
        chosen.append(j)
        c = cov[:, j].copy()
        cov -= np.outer(c, c) / c[j]
    mean_var = np.trace(cov) / len(cov)
    assert mean_var > TARGET_SD ** 2
    assert mean_var >= v[dof - 1:].sum() * (1 - 1e-6)           # the eigenvalue bound holds
    # and random designs of that size are further off
    rng = np.random.default_rng(1)
    for _ in range(3):
        pick = rng.choice(len(k), dof - 1, replace=False)
        kss = k[np.ix_(pick, pick)] + 1e-12 * np.eye(len(pick))
        post = np.diag(k) - np.sum(k[pick] * np.linalg.solve(kss, k[pick]), axis=0)
        assert post.mean() > TARGET_SD ** 2


def test_analytic_cases(board):
    v = mode_variances(PRIOR, board.samples, board.center)
    assert truncation_dof(v, math.sqrt(v.sum()) * 1.0001) == 0      # the prior already meets it
    # a rigid offset alone is one mode: sd 0.05 mm everywhere
    offset_only = DeviationPrior(amplitude_mm=1e-9, wavelength_mm=15.0, placement_xy_mm=0.0,
                                 placement_z_mm=0.05, placement_rz_deg=0.0, tilt_rad=0.0)
    w = mode_variances(offset_only, board.samples, board.center)
    assert w[0] == pytest.approx(0.05 ** 2, rel=1e-6) and w[1] < 1e-15
    assert truncation_dof(w, 0.001) == 1
    # a finer target never needs fewer modes
    counts = [truncation_dof(v, t) for t in (5e-3, 2.5e-3, 1.25e-3, 0.6e-3)]
    assert counts == sorted(counts) and counts[0] < counts[-1]


def test_the_grid_spacing_has_converged(board, monkeypatch):
    coarse = truncation_dof(mode_variances(PRIOR, board.samples, board.center), TARGET_SD)
    monkeypatch.setattr(field_dof, "GRID_PER_WAVELENGTH", 8)
    fine = truncation_dof(mode_variances(PRIOR, board.samples, board.center), TARGET_SD)
    assert abs(coarse - fine) <= 0.03 * fine


def test_the_plan_reports_both_counts_and_they_do_not_depend_on_the_trace_count():
    part = s1_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 9)]
    once = plan_field(paths, PARAMS)
    twice = plan_field(paths + paths, PARAMS)
    assert once.dof == twice.dof and once.nyquist_dof == pytest.approx(twice.nyquist_dof)
    region = field_region(paths, 15.0)
    assert once.nyquist_dof == pytest.approx(region.area_mm2 / 7.5 ** 2 + 6)
    assert once.dof == truncation_dof(mode_variances(PRIOR, region.samples, region.center), TARGET_SD)


def test_the_plans_dof_is_counted_when_first_read_once_and_equals_the_cold_count(monkeypatch):
    """The plan carries its dof deferred (an eigendecomposition a caller may never read): no
    count until it is read, one however often it is read, the same number the count from
    scratch gives, and a pickled plan (a compute process's result) counts the same."""
    part = s1_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 9)]
    counted = []
    cold = field_dof.mode_variances
    monkeypatch.setattr(field_dof, "mode_variances", lambda *a: counted.append(1) or cold(*a))
    plan = plan_field(paths, PARAMS)
    copy = pickle.loads(pickle.dumps(plan))
    assert counted == []
    region = field_region(paths, 15.0)
    expected = truncation_dof(cold(PRIOR, region.samples, region.center), TARGET_SD)
    assert plan.dof == expected and plan.dof == expected and len(counted) == 1
    assert copy.dof == expected and len(counted) == 2
    assert replace(plan, xy=plan.xy[:0]).dof == expected and len(counted) == 2
