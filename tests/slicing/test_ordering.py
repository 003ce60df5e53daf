"""Travel ordering: the greedy order found from a table of all distances at once, or from each
candidate's nearest neighbours, is the order the per-step search finds (the reference below
is that search as it was written before, nearest living candidate recomputed from the nozzle
at each step), ties and nearly closed loops included."""

from __future__ import annotations

import numpy as np
import pytest

import app.slicing.ordering as ordering
from app.slicing.ordering import order_paths


def _reference(paths, start):
    """The per-step greedy search: open paths by either end, closed ones from any vertex."""
    remaining = [np.asarray(p, dtype=float) for p in paths if len(p) >= 2]
    out, pos = [], np.asarray(start, dtype=float)
    alive = list(range(len(remaining)))
    while alive:
        best = None
        for k in alive:   # candidates in path order, first vertex before last; strict < keeps the lowest
            p = remaining[k]
            closed = len(p) > 2 and np.allclose(p[0], p[-1])
            for v, q in enumerate(p[:-1] if closed else p[[0, -1]]):
                d = (q[0] - pos[0]) * (q[0] - pos[0]) + (q[1] - pos[1]) * (q[1] - pos[1])
                if best is None or d < best[0]:
                    best = (d, k, v, closed)
        _, k, v, closed = best
        p = remaining[k]
        if closed and v:
            body = np.roll(p[:-1], -v, axis=0)
            p = np.vstack([body, body[:1]])
        elif not closed and v:
            p = p[::-1]
        out.append(p)
        alive.remove(k)
        pos = p[-1]
    return out


def _paths(rng, n_open, n_closed, grid):
    """Open segments and polylines, closed loops (some closed only within the tolerance),
    on a coarse grid when ``grid`` (many exact ties)."""
    def points(n):
        return rng.integers(0, 6, (n, 2)).astype(float) if grid else rng.uniform(0, 30, (n, 2))

    out = [points(int(rng.integers(2, 5))) for _ in range(n_open)]
    for _ in range(n_closed):
        ring = points(int(rng.integers(3, 7)))
        last = ring[:1] + (1e-9 if rng.random() < 0.5 else 0.0)   # nearly closed: its last vertex is its own
        out.append(np.vstack([ring, last]))
    return out


@pytest.mark.parametrize("matrix_candidates", [0, ordering.MATRIX_CANDIDATES])
@pytest.mark.parametrize("seed", range(16))
def test_the_greedy_order_is_the_per_step_search(monkeypatch, matrix_candidates, seed):
    monkeypatch.setattr(ordering, "MATRIX_CANDIDATES", matrix_candidates)
    rng = np.random.default_rng(seed)
    paths = _paths(rng, int(rng.integers(0, 40 if seed < 8 else 200)), int(rng.integers(0, 8)), grid=seed % 2 == 0)
    start = rng.uniform(0, 30, 2)
    got, end = order_paths(paths, start)
    want = _reference(paths, start)
    assert len(got) == len(want)
    for a, b in zip(got, want):
        assert np.array_equal(a, b)
    if want:
        assert np.array_equal(end, want[-1][-1])
