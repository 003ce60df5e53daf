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
from app.reconstruction.field_trust import checked_field, with_bound
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
    bound = DEFAULT.coverage * max(check.fit.posterior.sd(path_sites(p, p.s[::10])).max() for p in paths)
    check = with_bound(check, [bound / DEFAULT.coverage])
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
    assert not check.needs_attention, check.reasons
    after, before = true_errors(check.fit, paths)
    assert (after < before).all()
    assert after.max() <= check.bound_mm <= DEFAULT.target_error_mm
    assert check.verification is not None and check.verification.within.all()
    assert check.verified_line().startswith(f"verified at {len(check.verification.xy)} points: max |residual| ")


def stepped(xy: np.ndarray) -> np.ndarray:
    """The 14 mm part with a 20 um step up across x = 30 mm (a discontinuity the smooth field
    cannot represent): the truth (m,) mm at xy (m, 2)."""
    return fourteen(xy) + 0.02 * (xy[:, 0] > 30.0)


def test_a_step_in_the_part_is_not_verified_and_the_verdict_says_where(paths):
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
    outside = ~v.within
    assert outside.any() and (np.abs(v.xy[outside, 0] - 30.0) < 1.5).all()   # the points off the field are at the step
    line = check.verified_line()
    assert line.startswith(f"NOT verified at {len(v.xy)} points") and "worst at [30." in line


def test_gap_points_lie_midway_to_the_neighbours_of_the_worst_predicted_stations():
    from app.geometry.traces import TracePolyline
    from app.probing.field_verify import gap_points

    line = TracePolyline.from_points(np.column_stack([np.linspace(0, 20, 41), np.full(41, 5.0), np.zeros(41)]))
    trace = np.array([0, 0, 0, 0, 0, -1])
    s = np.array([0.0, 5.0, 10.0, 10.2, 20.0, np.nan])      # 10.2: a re-touch of the station at 10 (same spot)
    z = np.array([0.1, 0.5, -3.0, 0.2, 2.0, 9.0])            # off-trace station (z 9) has no gap along a trace
    points = gap_points([line], trace, s, z, stations=2)       # worst: s 10 (both sides), s 20 (the end: one side)
    assert np.allclose(points.s, [7.5, 15.0, 15.1])
    assert np.allclose(points.sites.xy, [[7.5, 5.0], [15.0, 5.0], [15.1, 5.0]])
    assert (points.trace == 0).all() and len(gap_points([line], trace, s, z, stations=0)) == 0
