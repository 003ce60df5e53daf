import itertools

import numpy as np
import pytest

from app.jetting.binarize import (
    binarize,
    error_diffusion_pattern,
    greedy_pattern,
    threshold_pattern,
)
from app.jetting.qp import solve_fista

from .helpers import small_qp


@pytest.mark.parametrize("method", ["threshold", "error_diffusion", "greedy"])
def test_integer_gap_is_nonnegative_and_pattern_is_on_the_part(method):
    qp, target = small_qp()
    sol = solve_fista(qp, tol=1e-8, max_iter=5000)
    result = binarize(qp, sol.x, sol.objective, method)
    assert result.integer_gap >= -1e-9
    assert result.pattern.dtype == bool and not result.pattern[~target.mask].any()
    assert result.objective == pytest.approx(qp.objective(np.stack([result.pattern.astype(float)])))


def test_greedy_never_worse_than_threshold_and_reaches_a_local_optimum():
    qp, _ = small_qp()
    sol = solve_fista(qp, tol=1e-8, max_iter=5000)
    start = threshold_pattern(sol.x[0], qp.free)
    pattern, flips = greedy_pattern(qp, sol.x, start, rounds=50)
    j_start = qp.objective(start[None].astype(float))
    j_greedy = qp.objective(pattern[None].astype(float))
    assert j_greedy <= j_start + 1e-12
    assert flips > 0 and j_greedy < j_start
    base = pattern.astype(float)
    for i, j in zip(*np.nonzero(qp.free)):  # no single flip improves any more
        trial = base.copy()
        trial[i, j] = 1.0 - trial[i, j]
        assert qp.objective(trial[None]) >= j_greedy - 1e-9


def test_threshold_is_the_integer_optimum_of_a_separable_qp():
    qp, _ = small_qp(dpi=300.0, model="seed_diagonal", steps=0, size=3)
    sol = solve_fista(qp, tol=1e-9)
    best = threshold_pattern(sol.x[0], qp.free)
    cells = list(zip(*np.nonzero(qp.free)))
    assert len(cells) <= 12
    values = []
    for bits in itertools.product([0.0, 1.0], repeat=len(cells)):
        f = np.zeros(qp.free.shape)
        for (i, j), b in zip(cells, bits):
            f[i, j] = b
        values.append(qp.objective(f[None]))
    assert qp.objective(best[None].astype(float)) == pytest.approx(min(values), rel=1e-12)


def test_error_diffusion_keeps_the_drop_count():
    rng = np.random.default_rng(5)
    relaxed = rng.random((40, 30)) * 0.6
    free = np.ones((40, 30), dtype=bool)
    out = error_diffusion_pattern(relaxed, free)
    assert abs(out.sum() - relaxed.sum()) <= 30
    assert abs(out[:20].sum() - relaxed[:20].sum()) <= 30


@pytest.mark.parametrize("radius", [0, 1, 2, 3])
def test_lee_colours_keep_same_colour_cells_apart(radius):
    from app.jetting.binarize import lee_colours

    colours, count = lee_colours((30, 30), radius)
    assert set(np.unique(colours)) == set(range(count))
    for c in range(count):
        pts = np.argwhere(colours == c)
        d = np.abs(pts[:, None, :] - pts[None, :, :]).sum(-1)
        d[np.arange(len(pts)), np.arange(len(pts))] = 10**6
        assert d.min() >= 2 * radius + 1
