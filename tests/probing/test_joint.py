"""Joint (part-level) kriging stations: the exchange's algebra, design invariants, the count
rule, and the reconstruction that uses every trace's probes."""

import numpy as np
import pytest

from app.geometry.traces import as_trace_polyline
from app.probing.deviation_prior import Sites, fit_posterior, path_sites
from app.probing.joint import (
    JointGrid,
    auto_joint_count,
    design_joint,
    even_joint_indices,
    joint_center,
    joint_exchange,
    joint_grid,
    move_variances,
    plan_joint,
    power_mean,
)
from app.probing.selection import PlanError, PlanParams
from app.reconstruction.preprocess import ReconstructionError
from app.reconstruction.reconstruct import ReconstructParams, reconstruct
from app.reference.s1 import as_made, nominal_path, s1_traces

PROCESS = dict(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)
PRIOR = PlanParams(**PROCESS).prior()


@pytest.fixture(scope="module")
def paths():
    """Three neighbouring S1 NURBS traces (7, 8, 9), 4 mm apart."""
    return [nominal_path(t, 0.1) for t in s1_traces()[6:9]]


@pytest.fixture(scope="module")
def grid(paths) -> JointGrid:
    return joint_grid(paths, PRIOR)


def test_power_mean_lies_between_the_mean_and_the_max():
    v = np.array([1.0, 2.0, 3.0, 10.0])
    assert power_mean(np.full(5, 4.0)) == pytest.approx(4.0)
    assert v.mean() < power_mean(v) < v.max()
    assert power_mean(v) == pytest.approx(np.mean(v ** 16) ** (1 / 16))
    assert power_mean(np.zeros(3)) == 0.0


def test_rank_one_move_scores_equal_a_fresh_posterior(grid):
    chosen = even_joint_indices(grid, 5)
    k = 7
    cand = np.arange(chosen[k - 1] + 1, chosen[k + 1])
    fast = move_variances(grid, chosen, k, cand)
    for row, j in zip(fast, cand):
        trial = chosen.copy()
        trial[k] = j
        assert np.allclose(row, grid.posterior_var(trial), rtol=1e-7, atol=1e-14)


def test_grid_covariance_is_the_priors_and_posterior_matches_fit_posterior(paths, grid):
    chosen = even_joint_indices(grid, 4)
    s_all = [grid.s[t] for t in range(len(paths))]
    per = [path_sites(p, s) for p, s in zip(paths, s_all)]
    sites = Sites(np.concatenate([q.xy for q in per]), np.concatenate([q.grad for q in per]))
    post = fit_posterior(PRIOR, sites.take(chosen), np.zeros(len(chosen)), center=grid.center)
    assert np.allclose(post.sd(sites) ** 2, grid.posterior_var(chosen), rtol=1e-6, atol=1e-14)


def test_joint_design_invariants_and_it_never_loses_to_even_spacing(paths, grid):
    for n in (5, 6):
        design = design_joint(grid, n)
        assert len(design.s_mm) == len(paths)
        for s, path in zip(design.s_mm, paths):
            assert len(s) == n and np.all(np.diff(s) > 0)
            assert s[0] >= 0 and s[-1] <= path.length_mm + 1e-12
        even = even_joint_indices(grid, n)
        chosen = joint_exchange(grid, even)
        assert power_mean(grid.posterior_var(chosen)) <= power_mean(grid.posterior_var(even))
        assert design.max_sd_mm == pytest.approx(np.sqrt(grid.posterior_var(chosen).max()))


def test_joint_design_beats_planning_each_trace_alone(paths, grid):
    """Same probes per trace: the joint stations leave a smaller largest sd over the part
    than the per-trace kriging stations judged by the same joint posterior."""
    n = 5
    joint = design_joint(grid, n)
    alone = [plan_joint([p], PlanParams(count=n, **PROCESS))[0].s_mm for p in paths]

    def largest_sd(stations):
        idx = [grid.offsets[t] + np.abs(grid.s[t][:, None] - s[None, :]).argmin(axis=0)
               for t, s in enumerate(stations)]
        return np.sqrt(grid.posterior_var(np.concatenate(idx)).max())

    assert largest_sd(joint.s_mm) < largest_sd(alone)


def test_auto_count_is_the_fewest_that_meet_the_target(grid):
    target, coverage = 0.005, 3.0
    n = auto_joint_count(grid, target, coverage, 4)
    assert coverage * design_joint(grid, n).max_sd_mm <= target
    assert coverage * design_joint(grid, n - 1).max_sd_mm > target


def test_plan_joint_returns_one_plan_per_trace_on_its_nominal(paths):
    plans = plan_joint(paths, PlanParams(count=6, **PROCESS))
    assert [p.count for p in plans] == [6, 6, 6]
    for plan, path in zip(plans, paths):
        assert plan.method == "kriging" and plan.predicted_sd_mm > 0
        assert np.allclose(plan.points, path.at(plan.s_mm))
    with pytest.raises(PlanError):
        plan_joint([], PlanParams())


def test_joint_center_weights_traces_by_length():
    a = as_trace_polyline(np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]))
    b = as_trace_polyline(np.array([[0.0, 10.0, 0.0], [30.0, 10.0, 0.0]]))
    assert np.allclose(joint_center([a, b]), [(10 * 5 + 30 * 15) / 40, (0 + 30 * 10) / 40])


def _measure(part, plans, rng):
    out = []
    for plan in plans:
        pts = plan.points.copy()
        pts[:, 2] = part.true_height(pts[:, :2]) + rng.normal(0.0, 0.001, len(pts))
        out.append(pts)
    return out


def test_context_probes_make_the_reconstruction_better(paths):
    """Five probes per trace on three neighbouring traces of an as-made part: each trace
    rebuilt with its neighbours' probes is closer to the truth than rebuilt alone."""
    plans = plan_joint(paths, PlanParams(count=5, **PROCESS))
    params = ReconstructParams(prior=PRIOR)
    with_ctx, alone = [], []
    for seed in (11, 12, 13):
        part = as_made(seed)
        measured = _measure(part, plans, np.random.default_rng(seed))
        for i, path in enumerate(paths):
            truth = part.true_height(path.points[:, :2])
            ctx = [(paths[j], measured[j]) for j in range(len(paths)) if j != i]
            joint = reconstruct(path, measured[i], "kriging", 0.001, params, context=ctx)
            single = reconstruct(path, measured[i], "kriging", 0.001, params)
            with_ctx.append(np.abs(joint.height_at_s(path.s) - truth).max())
            alone.append(np.abs(single.height_at_s(path.s) - truth).max())
            assert np.allclose(joint.samples, single.samples)  # its own samples only
    assert max(with_ctx) < 0.5 * max(alone)
    assert np.mean(with_ctx) < 0.6 * np.mean(alone)  # measured: 0.51


def test_crossing_traces_rebuilt_from_the_same_probes_agree_where_they_cross():
    """Both reconstructions are the same posterior field: equal deviation at the crossing."""
    base = nominal_path(s1_traces()[1], 0.1)  # a line along y at x = 10
    xy = np.stack([np.linspace(2.0, 30.0, 300), np.full(300, 20.0)], axis=1)
    from app.reference.s1 import nominal_gradient, nominal_height

    g = nominal_gradient(xy)
    normals = np.stack([-g[:, 0], -g[:, 1], np.ones(len(xy))], axis=1)
    cross = as_trace_polyline(type("T", (), {"points": np.column_stack([xy, nominal_height(xy)]),
                                           "normals": normals})())
    part = as_made(5)
    plans = plan_joint([base, cross], PlanParams(count=6, **PROCESS))
    measured = _measure(part, plans, np.random.default_rng(0))
    params = ReconstructParams(prior=PRIOR)
    a = reconstruct(base, measured[0], "kriging", 0.001, params, context=[(cross, measured[1])])
    b = reconstruct(cross, measured[1], "kriging", 0.001, params, context=[(base, measured[0])])
    at = np.array([[10.0, 20.0]])
    dev_a = a.deviation_at_s(base.project_xy(at).s)
    dev_b = b.deviation_at_s(cross.project_xy(at).s)
    # equal up to the two polylines' own discretisation (slopes, projection): ~1 nm
    assert dev_a == pytest.approx(dev_b, abs=1e-5)
    alone_a = reconstruct(base, measured[0], "kriging", 0.001, params)
    alone_b = reconstruct(cross, measured[1], "kriging", 0.001, params)
    gap = alone_a.deviation_at_s(base.project_xy(at).s) - alone_b.deviation_at_s(cross.project_xy(at).s)
    assert abs(gap[0]) > 1e-3  # rebuilt apart, the two disagree by micrometres


def test_context_is_refused_for_other_methods_and_bad_context_points_are_named(paths):
    pts = paths[0].at(np.linspace(0, paths[0].length_mm, 6))
    other = paths[1].at(np.linspace(0, paths[1].length_mm, 6))
    with pytest.raises(ReconstructionError) as exc:
        reconstruct(paths[0], pts, "deviation", 0.001, context=[(paths[1], other)])
    assert exc.value.field == "context"
    bad = other.copy()
    bad[2, 2] = np.nan
    with pytest.raises(ReconstructionError) as exc:
        reconstruct(paths[0], pts, "kriging", 0.001, context=[(paths[1], bad)])
    assert exc.value.field.startswith("context[0].points")
    with pytest.raises(ReconstructionError) as exc:  # another trace's points are not this one's
        reconstruct(paths[0], pts, "kriging", 0.001, context=[(paths[1], pts)])
    assert exc.value.field.startswith("context[0].points")
