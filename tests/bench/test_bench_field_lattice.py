"""Bench: how many stations a noise-limited target needs, whatever the design.

Run: .venv/bin/python -m pytest tests/bench/test_bench_field_lattice.py -s -o addopts="" -q

The field planner's count is compared with the Nyquist rule ``A / (lambda/2)^2 + 6``.  This bench asks
what ANY design needs on the same region: the 1000-trace S1 board (the region is nearly
the whole 52 x 32 mm top), prior A = 0.15 mm, lambda = 15 mm, 1 um probe noise, target sd
5 um / coverage 4 = 1.25 um.  Hexagonal lattices (the densest-efficient sampling of a
disk spectrum) of spacing h, stations inside the traces' bounding box or also up to
lambda / 4 outside it; printed: stations, stations / dof, largest and median posterior sd
over every trace sample.  Against them: the field planner's own design and the field's
degrees of freedom at the target (``plan.dof``, :mod:`app.probing.field_dof`): the fewest
stations n for which even the best rank-n update of the prior covariance over the covered
region brings the MEAN variance to the target, noise-free.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from app.probing.deviation_prior import Sites
from app.probing.field import plan_field, posterior_sd
from app.probing.field_region import field_region
from app.probing.selection import PlanParams
from app.reference.boards import board_path, board_traces, s1_part

PARAMS = PlanParams(coverage=4.0, deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)


def hexagonal(lo: np.ndarray, hi: np.ndarray, h: float) -> np.ndarray:
    rows = []
    for i, y in enumerate(np.arange(lo[1] - h, hi[1] + h, h * np.sqrt(3) / 2)):
        xs = np.arange(lo[0] - h + (h / 2) * (i % 2), hi[0] + h, h)
        rows.append(np.column_stack([xs, np.full(len(xs), y)]))
    return np.concatenate(rows)


def test_hexagonal_lattices_against_the_field_planner():
    part = s1_part()
    prior = PARAMS.prior()
    target = PARAMS.target_error_mm / PARAMS.coverage
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 1000)]
    region = field_region(paths, 15.0)
    samples = region.samples.sites
    lo, hi = samples.xy.min(axis=0), samples.xy.max(axis=0)
    plan = plan_field(paths, PARAMS)
    nyquist = region.nyquist_dof
    print(f"\n\nS1, 1000 traces: Nyquist count {nyquist:.1f}, dof at the target {plan.dof:.0f}; field planner "
          f"{plan.count} stations ({plan.count / nyquist:.2f} x Nyquist, {plan.count / plan.dof:.2f} x dof), "
          f"largest sd {plan.max_sd_mm * 1e3:.2f} um (target {target * 1e3:.2f})")
    print(f"{'h mm':>5} {'where':>14} {'stations':>8} {'x nyq':>6} {'max sd um':>9} {'median sd um':>12}")
    best_lattice = None
    for h in np.arange(5.0, 7.01, 0.5):
        grid = hexagonal(lo, hi, h)
        d, _ = cKDTree(samples.xy).query(grid)
        inside = (grid >= lo).all(axis=1) & (grid <= hi).all(axis=1)
        for where, keep in (("in the box", inside), ("+ lambda/4", d <= 15.0 / 4)):
            st = grid[keep]
            sd = posterior_sd(prior, Sites(st, part.gradient(st)), samples, region.center)
            print(f"{h:>5.2f} {where:>14} {len(st):>8} {len(st) / nyquist:>6.2f} {sd.max() * 1e3:>9.2f} "
                  f"{np.median(sd) * 1e3:>12.2f}")
            if sd.max() <= target and (best_lattice is None or len(st) < best_lattice):
                best_lattice = len(st)
    print(f"fewest lattice stations meeting the target: {best_lattice}; the field planner: {plan.count}")
    assert plan.max_sd_mm <= target * (1 + 1e-9)
    assert best_lattice is None or plan.count <= best_lattice
    assert plan.dof <= plan.count
