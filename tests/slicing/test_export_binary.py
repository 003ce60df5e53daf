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


def test_rings_stored_the_wrong_way_round_are_oriented_as_ring_by_ring():
    """The orientation of every ring at once (the shoelace sums of all rings together) turns
    the same rings as :func:`oriented` ring by ring: outer rings and holes written reversed,
    and sliver rings whose area is all rounding."""
    import io

    from app.slicing.export import from_document
    from app.slicing.rings import oriented

    data = to_binary(_parts()["tube"])
    with np.load(io.BytesIO(data)) as arrays:
        header, points, table = arrays["header"], arrays["points"].copy(), arrays["rings"].copy()
    ends = np.cumsum(table[:, 3])
    for i in range(0, len(table), 3):  # every third ring reversed in the file
        points[ends[i] - table[i, 3]:ends[i]] = points[ends[i] - table[i, 3]:ends[i]][::-1].copy()
    sliver = np.array([[0.0, 0.0], [1.0, 1e-17], [2.0, 0.0], [3.0, -1e-17]])  # area ~1e-17 mm^2
    points = np.vstack([points, sliver + 40.0, sliver[::-1] + 40.0])
    table = np.vstack([table, [table[-1, 0], 0, 1, 4], [table[-1, 0], 0, 1, 4]])  # two more holes, last layer
    out = io.BytesIO()
    np.savez(out, header=header, points=points, rings=table)
    ours = from_binary(out.getvalue())
    import json
    doc = json.loads(header.tobytes())
    contours: list[list[tuple[np.ndarray, list[np.ndarray]]]] = [[] for _ in doc["layers"]]
    starts = np.concatenate([[0], ends[:-1].tolist() + [ends[-1], ends[-1] + 4]])
    for (k, j, hole, n), start in zip(table.tolist(), starts.tolist()):
        ring = points[start:start + n]
        if hole:
            contours[k][j][1].append(ring)
        else:
            contours[k].append((ring, []))
    reference = from_document(doc, contours)  # ring by ring, through oriented
    rings = [r for lay in ours.layers for isl in lay.islands for r in isl.rings()]
    expected = [r for lay in reference.layers for isl in lay.islands for r in isl.rings()]
    assert len(rings) == len(expected) == len(table)
    for a, b in zip(rings, expected):
        assert np.array_equal(a, b)
    assert np.array_equal(expected[-1], oriented(sliver[::-1] + 40.0, ccw=False))


def test_layers_that_repeat_a_section_share_its_arrays_read_back_and_moved():
    """A prismatic stretch's layers share their rings' arrays as read back (the same numbers as
    the JSON reads, per layer), and moving the layers moves each shared array once."""
    from app.slicing.layers import translated

    sliced = slice_mesh(thin_tube(), SliceParams(mode="uniform", layer_mm=0.2))
    back, text = from_binary(to_binary(sliced)), from_json(to_json(sliced))
    shared = 0
    for before, layer, truth in zip(back.layers, back.layers[1:], text.layers[1:]):
        for a, b, c in zip(before.islands, layer.islands, truth.islands):
            for ra, rb, rc in zip(a.rings(), b.rings(), c.rings()):
                assert np.array_equal(rb, rc)
                if np.array_equal(ra, rb):
                    assert rb is ra
                    shared += 1
    assert shared >= len(back.layers) - 3
    moved = translated(back, np.array([1.5, -2.0, 0.25]))
    for layer, src in zip(moved.layers, back.layers):
        for isl, orig in zip(layer.islands, src.islands):
            for ring, o in zip(isl.rings(), orig.rings()):
                assert np.array_equal(ring, o + [1.5, -2.0])
    assert moved.layers[5].islands[0].outer is moved.layers[6].islands[0].outer
