"""Minimax probe stations for the kriging deviation model (planner ``"kriging"``).

Given the deviation prior (:mod:`app.probing.deviation_prior`), the posterior sd of the
reconstructed height along the trace depends only on where the probes are, not on what
they read.  The planner therefore picks the stations that minimise the **largest**
posterior sd along the trace (a minimax / G-optimal design), and the count as the fewest
probes whose ``coverage`` x largest sd meets the target error.

Algorithm: a target grid of G stations along the nominal (spacing ~ wavelength / 40,
G <= ``MAX_GRID``) carries one precomputed prior covariance (G, G).  Start from even
arc-length spacing; then coordinate exchange: each probe in turn moves to the grid
station between its neighbours that lowers the largest sd most; sweeps repeat until none
moves.  Measured on S1 (see the bench): the greedy "probe where the sd is largest"
sequential rule is worse than even spacing; the exchange design is better than both.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import (
    DeviationPrior,
    max_posterior_sd,
    path_center,
    path_sites,
    prior_covariance,
    prior_variance,
)

MAX_GRID = 401
MIN_GRID = 33
GRID_PER_WAVELENGTH = 40
MAX_EXCHANGE_COUNT = 60
MAX_SWEEPS = 8
MAX_AUTO_COUNT = 2000


@dataclass(frozen=True, eq=False)
class DesignGrid:
    """Target/candidate stations s (G,) mm with the prior covariance (G, G) mm^2."""

    s: np.ndarray
    cov: np.ndarray
    prior_var: np.ndarray
    sigma_mm: float

    def max_sd(self, chosen: np.ndarray) -> float:
        """Largest posterior sd (mm) over the grid with probes at grid indices ``chosen``."""
        return max_posterior_sd(self.cov, self.prior_var, np.asarray(chosen),
                                np.arange(len(self.s)), self.sigma_mm)


@dataclass(frozen=True, eq=False)
class StationDesign:
    """Chosen stations s_mm (n,) along the nominal and their largest posterior sd (mm)."""

    s_mm: np.ndarray
    max_sd_mm: float


def design_grid(path: TracePolyline, prior: DeviationPrior) -> DesignGrid:
    """The target grid of a trace (see the module doc)."""
    length = path.length_mm
    g = int(math.ceil(length / (prior.wavelength_mm / GRID_PER_WAVELENGTH))) + 1
    g = min(max(g, MIN_GRID), MAX_GRID)
    s = np.linspace(0.0, length, g)
    sites = path_sites(path, s)
    center = path_center(path)
    cov = prior_covariance(prior, sites, sites, center)
    prior_var = prior_variance(prior, sites, center)
    return DesignGrid(s, cov, prior_var, prior.sigma_mm)


def even_indices(grid_size: int, count: int) -> np.ndarray:
    """``count`` grid indices (n,) evenly spread over a grid of ``grid_size``, ends included."""
    return np.unique(np.round(np.linspace(0, grid_size - 1, count)).astype(int))


def exchange(grid: DesignGrid, chosen: np.ndarray) -> np.ndarray:
    """Coordinate exchange on grid indices (n,) minimising the largest posterior sd."""
    chosen = np.array(sorted(chosen), dtype=int)
    best = grid.max_sd(chosen)
    for _ in range(MAX_SWEEPS):
        moved = False
        for i in range(len(chosen)):
            lo = chosen[i - 1] + 1 if i > 0 else 0
            hi = chosen[i + 1] - 1 if i + 1 < len(chosen) else len(grid.s) - 1
            for j in range(lo, hi + 1):
                if j == chosen[i]:
                    continue
                trial = chosen.copy()
                trial[i] = j
                value = grid.max_sd(trial)
                if value < best - 1e-15:
                    best, chosen, moved = value, trial, True
        if not moved:
            break
    return chosen


def design_stations(grid: DesignGrid, count: int) -> StationDesign:
    """Minimax stations for ``count`` probes (even spacing when count > MAX_EXCHANGE_COUNT
    or the grid is too coarse to hold them apart)."""
    count = int(count)
    g = len(grid.s)
    if count >= g:
        s = np.linspace(0.0, float(grid.s[-1]), count)
        return StationDesign(s, float("nan"))
    chosen = even_indices(g, count)
    if count <= MAX_EXCHANGE_COUNT:
        chosen = exchange(grid, chosen)
    return StationDesign(grid.s[chosen], grid.max_sd(chosen))


def fewest_probes(even_ok: Callable[[int], bool], design_ok: Callable[[int], bool],
                  min_count: int, most: int) -> int:
    """Fewest probe count n >= min_count (>= 2) whose design meets a target.

    ``even_ok(n)``: even spacing meets it; ``design_ok(n)``: the optimised design does.
    Even spacing bounds the answer from above (doubling, then bisection: the sd falls as
    probes are added); the optimised design then walks down from that bound.  Returns
    ``most`` when even spacing never meets the target below it.
    """
    floor = max(min_count, 2)
    hi = floor
    while not even_ok(hi):
        if hi >= most:
            return most
        hi = min(2 * hi, most)
    lo = floor - 1
    while hi - lo > 1:  # even_ok(hi) holds, even_ok(lo) fails (or lo below the floor)
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if even_ok(mid) else (mid, hi)
    n = hi
    while n - 1 >= floor and design_ok(n - 1):
        n -= 1
    return n


def auto_count(grid: DesignGrid, target_mm: float, coverage: float, min_count: int) -> int:
    """Fewest probes whose minimax design has coverage x largest sd <= target_mm."""
    g = len(grid.s)
    return fewest_probes(
        lambda n: coverage * grid.max_sd(even_indices(g, n)) <= target_mm,
        lambda n: n <= MAX_EXCHANGE_COUNT and coverage * design_stations(grid, n).max_sd_mm <= target_mm,
        min_count, min(g, MAX_AUTO_COUNT))
