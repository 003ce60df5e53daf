"""Offsets (pyclipr) vs analytic areas and shapely; the seed's beam compensation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon

from app.slicing import SliceParams, slice_mesh
from app.slicing.errors import SlicingError
from app.slicing.offset import SEED_HAZ_TABLE, BeamWidthTable, compensate_beam, offset_islands
from app.slicing.rings import Island, signed_area
from tests.slicing.conftest import cavity_block

SQUARE = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
HOLE = np.array([[3, 3], [3, 7], [7, 7], [7, 3]], float)


@settings(max_examples=25, deadline=None)
@given(st.floats(0.01, 1.4))
def test_inward_offset_of_square_with_hole(d):
    out = offset_islands((Island(SQUARE, (HOLE,)),), -d)
    assert len(out) == 1 and len(out[0].holes) == 1
    assert out[0].area == pytest.approx((10 - 2 * d) ** 2 - (4 + 2 * d) ** 2, abs=1e-4)
    assert signed_area(out[0].outer) > 0 and signed_area(out[0].holes[0]) < 0


def test_round_offset_matches_shapely_buffer():
    th = np.linspace(0, 2 * np.pi, 7, endpoint=False)
    hexagon = np.c_[np.cos(th), np.sin(th)] * 5
    ours = offset_islands((Island(hexagon),), 0.7, join="round")[0].area
    ref = Polygon(hexagon).buffer(0.7, quad_segs=64).area
    assert ours == pytest.approx(ref, rel=2e-3)


def test_offset_can_split_an_island():
    dumbbell = np.array([[0, 0], [4, 0], [4, 1.8], [6, 1.8], [6, 0], [10, 0], [10, 4],
                         [6, 4], [6, 2.2], [4, 2.2], [4, 4], [0, 4]], float)
    assert len(offset_islands((Island(dumbbell),), -0.5)) == 2


def test_seed_haz_table_interpolates():
    assert SEED_HAZ_TABLE.width(0.020) == pytest.approx(0.021)
    assert SEED_HAZ_TABLE.width(0.0325) == pytest.approx((0.024 + 0.0255) / 2)
    assert SEED_HAZ_TABLE.width(0.1) == pytest.approx(0.028)     # clamped at the end
    with pytest.raises(SlicingError):
        BeamWidthTable((0.03, 0.02), (0.1, 0.2)).width(0.025)


def test_compensate_beam_shrinks_each_layer_by_its_width():
    res = slice_mesh(cavity_block(2, radius=1.0), SliceParams(mode="uniform", layer_mm=0.03))
    comp = compensate_beam(res)
    w = SEED_HAZ_TABLE.width(0.03)
    for a, b in zip(res.layers, comp.layers):
        isl = b.islands[0]
        assert isl.outer_area == pytest.approx((40 - 2 * w) * (10 - 2 * w), rel=1e-6)
        assert b.inner_ring_count == a.inner_ring_count
        assert b.area < a.area


def test_constant_beam_offset_and_bad_value():
    res = slice_mesh(cavity_block(1, radius=1.0), SliceParams(layer_mm=1.0))
    comp = compensate_beam(res, 0.1)
    assert comp.layers[0].area == pytest.approx(39.8 * 9.8, rel=1e-6)
    with pytest.raises(SlicingError) as e:
        compensate_beam(res, -0.1)
    assert e.value.field == "offset_mm"
