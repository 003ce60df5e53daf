"""Prismatic bands: where only vertical faces cross a band of heights, one section serves it.

The truth is manifold3d's own section at each layer's height (:func:`section_at`), compared as
regions (shapely: the symmetric difference's area, against the boundary's length), since the
rings a band shares keep the collinear points where the walls' diagonals cross at the height
it was first taken.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import trimesh

from app.slicing.layers import SliceParams, section_at
from app.slicing.mesh_prep import prepare_mesh, prism_bands
from app.slicing.slicer import slice_mesh
from tests.helpers.real_parts import cad_part, thin_tube


def _region(islands) -> shapely.Geometry:
    return shapely.union_all([shapely.Polygon(isl.outer, [h for h in isl.holes]) for isl in islands])


def _frustum() -> trimesh.Trimesh:
    """A cone cut flat: every side face slanted (a draft), so no band is prismatic."""
    cone = trimesh.creation.cone(radius=10.0, height=30.0, sections=64)
    return trimesh.intersections.slice_mesh_plane(cone, [0, 0, -1], [0, 0, 20.0], cap=True)


def test_bands_of_a_box_a_frustum_and_a_stepped_part():
    heights, prism = prism_bands(*_inputs(trimesh.creation.box((20.0, 20.0, 20.0))))
    assert heights.tolist() == [-10.0, 10.0] and prism.tolist() == [True]
    heights, prism = prism_bands(*_inputs(_frustum()))
    assert len(prism) >= 1 and not prism.any()
    # two boxes stacked (a step at z = 5): both bands prismatic, the step is a vertex height
    a, b = trimesh.creation.box((20.0, 20.0, 10.0)), trimesh.creation.box((10.0, 10.0, 10.0))
    b.apply_translation([0.0, 0.0, 10.0])
    heights, prism = prism_bands(*_inputs(trimesh.util.concatenate([a, b])))
    assert heights.tolist() == [-5.0, 5.0, 15.0] and prism.tolist() == [True, True]


def _inputs(mesh: trimesh.Trimesh):
    tri = mesh.vertices[mesh.faces]
    face_z = np.stack([tri[:, :, 2].min(axis=1), tri[:, :, 2].max(axis=1)], axis=1)
    return mesh.vertices[:, 2], mesh.face_normals[:, 2], face_z


@pytest.mark.parametrize("make", [lambda: trimesh.creation.box((20.0, 20.0, 20.0)), thin_tube,
                                  lambda: cad_part(refine=1), _frustum], ids=["cube", "tube", "cad part", "frustum"])
def test_every_layer_is_the_region_manifold_cuts_at_its_height(make):
    prepared = prepare_mesh(make())
    sliced = slice_mesh(prepared, SliceParams(mode="uniform", layer_mm=0.2))
    shared = 0
    for before, layer in zip((None, *sliced.layers), sliced.layers):
        truth = section_at(prepared.solid, layer.z_sample)
        ours, theirs = _region(layer.islands), _region(truth)
        # the same region to round-off: a band's shared rings differ from manifold's at this height only
        # by where rounding put the collinear points (on average < 1e-8 mm off the walls)
        assert ours.symmetric_difference(theirs).area < 1e-8 * theirs.length
        assert layer.area == pytest.approx(theirs.area, rel=1e-9)
        if before is not None and layer.islands is before.islands:
            shared += 1
        elif prepared.prism_band(layer.z_sample) is None:  # outside the bands: manifold's own rings
            assert len(layer.islands) == len(truth)
            for a, b in zip(layer.islands, truth):
                for ra, rb in zip(a.rings(), b.rings()):
                    assert np.array_equal(ra, rb)
    if make is _frustum:
        assert shared == 0
    else:
        assert shared > 0


def test_the_exports_of_shared_rings_are_those_of_the_same_rings_unshared():
    """Every export of a slice whose layers share their rings (SLC, CLI, JSON, layers.npz) is
    byte for byte that of the same slice with each layer's rings copied apart."""
    import dataclasses

    from app.jobs.kinds.slice import _contour_mm
    from app.slicing.export import SlcOptions, to_cli, to_json, to_slc
    from app.slicing.export_binary import to_binary
    from app.slicing.rings import Island, ring_length

    shared = slice_mesh(thin_tube(), SliceParams(mode="uniform", layer_mm=0.2))
    assert shared.layers[10].islands is shared.layers[11].islands
    apart = dataclasses.replace(shared, layers=tuple(
        dataclasses.replace(lay, islands=tuple(Island(isl.outer.copy(), tuple(h.copy() for h in isl.holes))
                                               for isl in lay.islands)) for lay in shared.layers))
    assert to_slc(shared, SlcOptions()).data == to_slc(apart, SlcOptions()).data
    assert to_cli(shared) == to_cli(apart) and to_json(shared) == to_json(apart)
    assert to_binary(shared) == to_binary(apart)
    assert _contour_mm(shared) == _contour_mm(apart) == sum(
        ring_length(r) for lay in apart.layers for isl in lay.islands for r in isl.rings())
