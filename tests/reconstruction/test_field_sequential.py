"""The sequential planner's round decisions: a design's run bound known before it is touched,
and the loosest pointwise target whose design meets the verdict's tolerance."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from app.probing.field import plan_field
from app.probing.selection import PlanParams
from app.reconstruction.field_learning import learn_prior
from app.reconstruction.field_sequential import AIM, LOOSE_TARGETS, design_bound, loosest_plan, stations_check
from app.reconstruction.field_trust import TARGET_SLACK
from app.reference.s1 import nominal_path, s1_traces

DEFAULT = PlanParams()


def smooth(xy: np.ndarray) -> np.ndarray:
    """A 30-40 mm error (m,) mm at xy (m, 2): the analytic truth."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.08 * np.sin(2 * np.pi * x / 40 + 0.3) * np.cos(2 * np.pi * y / 30) + 0.001 * (x - 20)


def test_a_designs_bound_is_the_verdicts_bound_of_the_same_stations_whatever_they_read():
    paths = [nominal_path(t, 0.05) for t in s1_traces()[:7]]
    plan = plan_field(paths, DEFAULT)
    rng = np.random.default_rng(3)
    dz = smooth(plan.xy) + rng.normal(0.0, 0.001, plan.count)
    learned = learn_prior(DEFAULT.prior(), plan.sites, dz, plan.center)
    verdict = stations_check(DEFAULT.prior(), plan.sites, dz, plan.center, plan.trace, plan.s_mm, paths,
                             DEFAULT.coverage, DEFAULT.target_error_mm)
    assert not verdict.fit.outliers   # the verdict fits every station: the same posterior
    predicted = design_bound(learned, plan.sites, plan.center, paths, DEFAULT.coverage)
    assert predicted == pytest.approx(verdict.bound_mm, rel=1e-6)
    # fewer stations: a larger bound (the posterior between them is wider)
    half = plan.sites.take(np.arange(0, plan.count, 2))
    assert design_bound(learned, half, plan.center, paths, DEFAULT.coverage) > predicted


def test_the_loosest_target_whose_design_meets_the_tolerance_is_planned():
    target = 5.0
    asked: list[float] = []

    def plan(t: float) -> SimpleNamespace:   # a looser target: fewer stations, a larger bound
        asked.append(t)
        return SimpleNamespace(count=int(100 / t), bound=0.95 * t)

    def bound_of(more: SimpleNamespace) -> float:
        return more.bound
    more = loosest_plan(plan, bound_of, target)  # type: ignore[arg-type]
    limit = AIM * TARGET_SLACK * target
    assert more is not None and more.bound <= limit
    tried = [f * target for f in LOOSE_TARGETS]
    assert asked == tried[:len(asked)]
    assert len(asked) == 2 and all(0.95 * t > limit for t in asked[:-1])   # every looser one tried first was over it
    assert loosest_plan(lambda t: SimpleNamespace(count=1, bound=99.0), bound_of, target) is None  # type: ignore[arg-type]
