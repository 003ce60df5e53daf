"""Minimax stations and the "kriging" planner (design quality, count rule, end to end)."""

import numpy as np
import pytest

from app.geometry.traces import as_trace_polyline
from app.probing.deviation_prior import fit_posterior, path_center, path_sites
from app.probing.minimax import auto_count, design_grid, design_stations, even_indices
from app.probing.selection import PlanParams, plan_probes
from app.reconstruction.reconstruct import ReconstructParams, reconstruct
from app.reference.s1 import as_made, nominal_path, s1_traces

PROCESS = dict(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)


@pytest.fixture(scope="module")
def path():
    return nominal_path(s1_traces()[6], 0.1)


@pytest.fixture(scope="module")
def grid(path):
    return design_grid(path, PlanParams(**PROCESS).prior())


def test_exchange_design_beats_even_spacing_and_reports_its_sd(path, grid):
    for n in (5, 7):
        design = design_stations(grid, n)
        assert len(design.s_mm) == n and np.all(np.diff(design.s_mm) > 0)
        assert design.max_sd_mm <= grid.max_sd(even_indices(len(grid.s), n)) + 1e-15
        # the reported sd is the posterior's, recomputed independently on the grid
        prior = PlanParams(**PROCESS).prior()
        post = fit_posterior(prior, path_sites(path, design.s_mm), np.zeros(n),
                             center=path_center(path))
        assert post.sd(path_sites(path, grid.s)).max() == pytest.approx(design.max_sd_mm,
                                                                         rel=1e-6)


def test_auto_count_is_the_fewest_that_meet_the_target(grid):
    target, coverage = 0.005, 3.0
    n = auto_count(grid, target, coverage, 4)
    assert coverage * design_stations(grid, n).max_sd_mm <= target
    assert coverage * design_stations(grid, n - 1).max_sd_mm > target


def test_mirrored_design_on_a_flat_straight_trace_is_equally_good():
    pts = np.column_stack([np.zeros(301), np.linspace(0, 30, 301), np.full(301, 5.0)])
    normals = np.tile([0.0, 0.0, 1.0], (301, 1))
    flat = as_trace_polyline(type("T", (), {"points": pts, "normals": normals})())
    g = design_grid(flat, PlanParams(**PROCESS).prior())
    design = design_stations(g, 6)
    idx = np.searchsorted(g.s, design.s_mm)
    mirrored = len(g.s) - 1 - idx[::-1]
    assert g.max_sd(mirrored) == pytest.approx(design.max_sd_mm, rel=1e-9)
    assert design.max_sd_mm < g.max_sd(even_indices(len(g.s), 6))


def test_kriging_plan_and_reconstruction_meet_the_target_on_an_as_made_part(path):
    params = PlanParams(target_error_mm=0.005, **PROCESS)
    plan = plan_probes(path, "kriging", params)
    assert plan.method == "kriging" and plan.count >= params.min_count
    assert 3.0 * plan.predicted_sd_mm <= 0.005
    assert np.allclose(plan.points, path.at(plan.s_mm))
    part = as_made(21)
    rng = np.random.default_rng(7)
    pts = plan.points.copy()
    pts[:, 2] = part.true_height(pts[:, :2]) + rng.normal(0, 0.001, len(pts))
    rec = reconstruct(path, pts, "kriging", sigma_mm=0.001,
                      params=ReconstructParams(prior=params.prior()))
    truth = part.true_height(path.points[:, :2])
    assert np.abs(rec.height_at_s(path.s) - truth).max() <= 0.005
    # the seed's interpolation through the same few probes is far worse
    seed = reconstruct(path, pts, "interpolate", sigma_mm=0.001)
    assert np.abs(seed.height_at_s(path.s) - truth).max() > 0.005
