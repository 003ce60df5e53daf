"""layers.json read back by ``from_json``: same layers, same contours, same fills."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.slicing import SliceParams, slice_mesh
from app.slicing.errors import SlicingError
from app.slicing.export import from_json, to_cli, to_json
from app.slicing.offset import compensate_beam
from app.slicing.rings import signed_area
from app.slicing.toolpath import ToolpathParams, plan_toolpath
from tests.slicing.conftest import cavity_block


@pytest.fixture(scope="module")
def sliced():
    return slice_mesh(cavity_block(2), SliceParams(mode="cavity", l_min=0.25, l_max=1.0,
                                                    sigma0=0.02))


def test_round_trip_keeps_layers_contours_and_params(sliced):
    back = from_json(to_json(sliced))
    assert back.params == sliced.params
    assert (back.z_min, back.z_max) == (sliced.z_min, sliced.z_max)
    assert np.array_equal(back.bounds, sliced.bounds) and back.volume == sliced.volume
    assert back.notes == sliced.notes and back.repairs == sliced.repairs
    assert len(back.layers) == len(sliced.layers)
    for a, b in zip(sliced.layers, back.layers):
        assert (a.index, a.reason, a.ring_count, a.inner_ring_count) == \
            (b.index, b.reason, b.ring_count, b.inner_ring_count)
        assert b.thickness == pytest.approx(a.thickness, abs=1e-9)
        assert len(a.islands) == len(b.islands)
        for ia, ib in zip(a.islands, b.islands):
            assert np.allclose(ia.outer, ib.outer, atol=5e-7) and signed_area(ib.outer) > 0
            assert all(np.allclose(ha, hb, atol=5e-7) and signed_area(hb) < 0
                       for ha, hb in zip(ia.holes, ib.holes))
            assert ib.area == pytest.approx(ia.area, rel=1e-6)
    # a second trip is exact (the contours are already at the JSON precision)
    assert to_json(from_json(to_json(back))) == to_json(back)
    assert to_cli(back) == to_cli(from_json(to_json(back)))


def test_toolpath_from_the_json_equals_the_toolpath_from_the_slice(sliced):
    params = ToolpathParams(pattern="raster", line_width_mm=0.8, perimeters=1)
    a = plan_toolpath(sliced, params).totals
    b = plan_toolpath(from_json(to_json(sliced)), params).totals
    assert (a.turns, a.jumps) == (b.turns, b.jumps)
    assert b.path_mm == pytest.approx(a.path_mm, rel=1e-6)
    assert b.time_s == pytest.approx(a.time_s, rel=1e-6)


def test_compensated_contours_survive_the_trip(sliced):
    comp = compensate_beam(sliced, 0.1)
    back = from_json(to_json(comp))
    assert [lay.area for lay in back.layers] == pytest.approx([lay.area for lay in comp.layers],
                                                               rel=1e-6)
    assert back.layers[0].area < sliced.layers[0].area


@pytest.mark.parametrize("text", ["not json", "{}", '{"mode": "uniform", "layers": []}',
                                  '{"params": {"nope": 1}, "layers": []}'])
def test_garbage_is_a_slicing_error(text):
    with pytest.raises(SlicingError) as err:
        from_json(text)
    assert err.value.field == "layers.json"


def test_a_bad_ring_names_its_layer(sliced):
    doc = json.loads(to_json(sliced))
    doc["layers"][1]["islands"][0]["outer"] = [[0, 0], [1, 1]]
    with pytest.raises(SlicingError) as err:
        from_json(json.dumps(doc))
    assert err.value.field == "layers[1].outer"
