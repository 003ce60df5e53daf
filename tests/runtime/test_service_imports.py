"""What the service's processes import, and the quantiles that spare them scipy.stats.

scipy.stats costs each process that imports it ~17 MiB of resident memory over the rest of
scipy the service loads (the server, the fork server and every compute process forked from
it).  The core needs only normal and chi-square quantiles: scipy.special's functions, which
scipy.stats itself evaluates (``norm.ppf`` is ``ndtri``, ``chi2.isf(q, n)`` is ``chdtri(n, q)``).
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from app.probing.deviation_prior import DeviationPrior, Sites
from app.probing.point_count import seed_point_count
from app.reconstruction.field_learning import loo_check
from app.reconstruction.field_trust import joint_coverage

IMPORTS = """
import importlib, sys
import app.main
from app.runtime.compute_pool import PRELOAD
from app.runtime.registry import kind_modules
for name in PRELOAD + kind_modules():
    importlib.import_module(name)
print(sorted(m for m in sys.modules if m == "scipy.stats" or m.startswith("scipy.stats.")))
"""


def test_neither_the_server_nor_the_compute_core_imports_scipy_stats():
    out = subprocess.run([sys.executable, "-c", IMPORTS], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.strip() == "[]", out.stdout[:500]


@pytest.mark.parametrize("confidence", [0.5, 0.9, 0.95, 0.99, 0.999999, 1e-12])
def test_the_point_count_quantile_is_the_normal_one(confidence):
    assert seed_point_count(0.3, confidence).z_gamma == float(stats.norm.ppf(confidence))


@pytest.mark.parametrize("coverage", [0.5, 1.0, 2.0, 2.5758, 3.0, 6.0])
@pytest.mark.parametrize("count", [0, 1, 2, 17, 1000, 10 ** 6])
def test_the_joint_coverage_is_bonferroni_on_the_normal(coverage, count):
    assert joint_coverage(coverage, count) == float(stats.norm.isf(stats.norm.sf(coverage) / max(count, 1)))


@pytest.mark.parametrize("n", [3, 12, 60])
def test_the_loo_limits_are_the_normal_and_chi_square_quantiles(n):
    rng = np.random.default_rng(n)
    prior = DeviationPrior(amplitude_mm=0.1, wavelength_mm=15.0, sigma_mm=0.002)
    sites = Sites(rng.uniform(0.0, 60.0, (n, 2)), np.zeros((n, 2)))
    check = loo_check(prior, sites, rng.normal(0.0, 0.05, n), np.zeros(2), alpha=0.01)
    assert check.z_limit == float(stats.norm.isf(0.01 / (2 * n)))
    assert check.statistic_limit == float(stats.chi2.isf(0.01, n) / n)
