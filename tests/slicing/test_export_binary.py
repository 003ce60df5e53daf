"""layers.npz reads back exactly what layers.json reads back, and refuses what it is not."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.slicing import SliceParams, SlicingError, slice_mesh
from app.slicing.export import from_json, to_json
from app.slicing.export_binary import from_binary, to_binary
from tests.helpers.real_parts import cad_part, thin_tube


def _parts():
    box = trimesh.creation.box((12.0, 7.0, 3.0))
    box.apply_translation([-6.0, 5.0, 0.0] - box.bounds[0])   # negative x: signs and -0.000000
    return {"cad": slice_mesh(cad_part(refine=1), SliceParams(layer_mm=0.5)),
            "tube": slice_mesh(thin_tube(), SliceParams(layer_mm=1.0)),
            "box": slice_mesh(box, SliceParams(layer_mm=0.3, mode="uniform"))}


@pytest.mark.parametrize("name", ["cad", "tube", "box"])
def test_the_arrays_read_back_bit_for_bit_what_the_json_reads_back(name):
    sliced = _parts()[name]
    ours, reference = from_binary(to_binary(sliced)), from_json(to_json(sliced))
    assert len(ours.layers) == len(reference.layers) > 0
    for a, b in zip(ours.layers, reference.layers):
        assert (a.index, a.z_bottom, a.z_top, a.z_sample, a.thickness, a.area, a.ring_count, a.inner_ring_count,
                a.sigma, a.mu, a.eps, a.reason) == (b.index, b.z_bottom, b.z_top, b.z_sample, b.thickness, b.area,
                                                      b.ring_count, b.inner_ring_count, b.sigma, b.mu, b.eps, b.reason)
        assert len(a.islands) == len(b.islands)
        for ia, ib in zip(a.islands, b.islands):
            assert len(ia.holes) == len(ib.holes)
            for ra, rb in zip(ia.rings(), ib.rings()):
                assert ra.dtype == rb.dtype and np.array_equal(ra, rb)
                assert not np.signbit(ra[ra == 0]).any()     # no -0.0, as the text has none
    assert np.array_equal(ours.bounds, reference.bounds)
    assert (ours.params, ours.z_min, ours.z_max, ours.repairs, ours.notes) == \
        (reference.params, reference.z_min, reference.z_max, reference.repairs, reference.notes)
    assert ours.volume == reference.volume


def test_what_is_not_a_layers_array_file_is_refused_naming_it():
    for data in (b"", b"PK\x03\x04 not a zip", to_json(_parts()["box"]).encode()):
        with pytest.raises(SlicingError) as info:
            from_binary(data)
        assert info.value.field == "layers.npz"
