"""Fill patterns: stay inside the ring, cover it, the improved fractal's single circuit, turn counts."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, MultiLineString, Polygon

from app.slicing import SliceParams, slice_mesh
from app.slicing.fractal import hilbert_d2xy, hilbert_fill, merged_fractal_fill
from app.slicing.ordering import order_paths
from app.slicing.rings import Island
from app.slicing.toolpath import PATTERNS, ToolpathParams, count_turns, plan_toolpath
from tests.slicing.conftest import cavity_block

W = 0.4


def _disc_with_hole():
    th = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    outer = np.c_[9 * np.cos(th), 9 * np.sin(th)]
    hole = np.c_[2.5 * np.cos(-th) + 2, 2.5 * np.sin(-th) - 1]
    return (Island(outer, (hole,)),)


class _FakeLayer:
    def __init__(self, islands, index=0):
        self.islands, self.index = islands, index
        self.z_top, self.thickness = 0.2 * (index + 1), 0.2


class _FakeSlice:
    def __init__(self, islands, n=1):
        self.layers = [_FakeLayer(islands, k) for k in range(n)]


@pytest.mark.parametrize("pattern", PATTERNS)
def test_fill_inside_and_covering(pattern):
    islands = _disc_with_hole()
    region = Polygon(islands[0].outer, list(islands[0].holes))
    tp = plan_toolpath(_FakeSlice(islands, 2), ToolpathParams(pattern=pattern, line_width_mm=W))
    for lay in tp.layers:
        lines = [p.points for p in lay.pieces]
        # centrelines inside the ring shrunk by half a line width: no bead outside the ring
        inner = region.buffer(-W / 2 + 1e-6)
        outside = max(float(shapely.distance(inner, shapely.points(p)).max()) for p in lines)
        assert outside <= 1e-6
        beads = MultiLineString([LineString(p) for p in lines]).buffer(W / 2)
        coverage = beads.intersection(region).area / region.area
        # plain Hilbert turns in most cells: each 90-degree turn leaves the cell corner
        # outside the round bead ((1 - pi/4) / 4 of a cell), a real under-fill of the
        # pattern (measured 96 %); every other pattern must cover >= 98 %
        assert coverage >= (0.95 if pattern == "hilbert" else 0.98), (pattern, coverage)
        assert lay.stats.path_mm == pytest.approx(
            sum(LineString(p).length for p in lines))
        assert lay.stats.time_s > lay.stats.path_mm / 40.0 * 0.9


def test_merged_fractal_is_one_circuit_per_region_and_beats_hilbert():
    islands = _disc_with_hole()
    merged = merged_fractal_fill(islands, W)
    plain = hilbert_fill(islands, W)
    assert len(merged) == 1                                     # no islands
    loop = merged[0]
    assert np.allclose(loop[0], loop[-1])
    seg = np.diff(loop, axis=0)
    assert np.all(np.isclose(seg[:, 0], 0) | np.isclose(seg[:, 1], 0))   # grid-aligned
    assert LineString(loop).is_simple or shapely.Polygon(loop).is_valid   # no self-crossing
    thr = math.radians(10)
    assert count_turns(loop, thr) < 0.5 * sum(count_turns(p, thr) for p in plain)
    assert len(plain) > 1                                       # Hilbert breaks at the hole
    two = (Island(np.array([[0, 0], [4, 0], [4, 4], [0, 4.0]])),
           Island(np.array([[10, 0], [14, 0], [14, 4], [10, 4.0]])))
    assert len(merged_fractal_fill(two, W)) == 2


def test_hilbert_curve_is_a_unit_step_path():
    ij = hilbert_d2xy(4, np.arange(256))
    assert len({tuple(p) for p in ij}) == 256
    assert np.all(np.abs(np.diff(ij, axis=0)).sum(axis=1) == 1)


def test_ordering_reduces_travel():
    rng = np.random.default_rng(1)
    starts = rng.uniform(0, 50, (40, 2))
    segs = [np.array([s, s + [1.0, 0.0]]) for s in starts]
    ordered, _ = order_paths(segs, np.zeros(2))
    def travel(seq):
        pos, tot = np.zeros(2), 0.0
        for p in seq:
            tot += np.hypot(*(p[0] - pos))
            pos = p[-1]
        return tot
    assert travel(ordered) < 0.5 * travel(segs)
    assert sorted(map(tuple, np.vstack(ordered).round(9))) == \
        sorted(map(tuple, np.vstack(segs).round(9)))


def test_toolpath_on_sliced_cavity_part():
    res = slice_mesh(cavity_block(3, size=(20.0, 8.0, 1.0), band=(0.2, 0.8), radius=1.0),
                     SliceParams(layer_mm=0.25))
    tp = plan_toolpath(res, ToolpathParams(pattern="hilbert_merged", perimeters=2))
    mid = tp.layers[2]
    assert sum(1 for p in mid.pieces if p.kind == "perimeter") == 2 * 4   # 2 x (outer + 3)
    assert tp.totals.path_mm == pytest.approx(sum(x.stats.path_mm for x in tp.layers))
    assert tp.totals.jumps == sum(x.stats.jumps for x in tp.layers)
    assert "marlin-jd" in tp.estimator
