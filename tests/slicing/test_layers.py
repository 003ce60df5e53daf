"""slice_mesh: analytic areas, ring nesting/orientation, layer counts, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from app.platform.problems import http_status
from app.slicing import SliceParams, slice_mesh
from app.slicing.errors import MeshError, SlicingError
from app.slicing.rings import signed_area
from tests.slicing.conftest import cavity_block

N_SIDES = 256


def polygon_area(r: float, n: int = N_SIDES) -> float:
    """Area of the regular n-gon inscribed in a circle of radius r."""
    return 0.5 * n * r * r * math.sin(2 * math.pi / n)


def test_cylinder_area_and_uniform_count():
    cyl = trimesh.creation.cylinder(radius=5.0, height=7.0, sections=N_SIDES)
    res = slice_mesh(cyl, SliceParams(mode="uniform", layer_mm=0.3))
    assert len(res.layers) == round(7.0 / 0.3) == 23          # 7 / 0.3 = 23.33: remainder distributed
    assert np.allclose(res.thicknesses, 7.0 / 23)
    merged = slice_mesh(cyl, SliceParams(mode="uniform", layer_mm=0.3, remainder="merge"))
    assert len(merged.layers) == 23                             # 0.1 mm rest < half a layer: merged
    assert merged.layers[-1].thickness == pytest.approx(0.4) and np.allclose(merged.thicknesses[:-1], 0.3)
    for lay in res.layers:
        assert lay.area == pytest.approx(polygon_area(5.0), rel=1e-9)
        assert lay.ring_count == 1 and lay.inner_ring_count == 0
    assert abs(polygon_area(5.0) - math.pi * 25) / (math.pi * 25) < 1e-3


def test_cone_area_follows_radius():
    cone = trimesh.creation.cone(radius=10.0, height=20.0, sections=N_SIDES)
    res = slice_mesh(cone, SliceParams(mode="uniform", layer_mm=0.5))
    for lay in res.layers:
        r = 10.0 * (1 - lay.z_sample / 20.0)
        assert lay.area == pytest.approx(polygon_area(r), rel=1e-7)
    volume = sum(lay.area * lay.thickness for lay in res.layers)
    assert volume == pytest.approx(res.volume, rel=2e-3)   # midpoint rule on a cone


@pytest.mark.parametrize("n", [1, 3, 7])
def test_n_cavities_give_n_inner_rings_in_band(n):
    res = slice_mesh(cavity_block(n), SliceParams(mode="uniform", layer_mm=0.25))
    for lay in res.layers:
        in_band = 2.0 < lay.z_sample < 4.0
        assert lay.inner_ring_count == (n if in_band else 0)
        assert len(lay.islands) == 1
        isl = lay.islands[0]
        assert signed_area(isl.outer) > 0                     # outer anticlockwise
        assert all(signed_area(h) < 0 for h in isl.holes)     # holes clockwise
        expect = 400.0 - (n * polygon_area(1.2, 48) if in_band else 0.0)
        assert lay.area == pytest.approx(expect, rel=1e-6)   # float32 mesh
        if in_band:
            assert lay.sigma == pytest.approx(n * polygon_area(1.2, 48) / 400.0)


def test_bad_parameters_are_named():
    cyl = trimesh.creation.cylinder(radius=1.0, height=1.0)
    with pytest.raises(SlicingError) as e:
        slice_mesh(cyl, SliceParams(mode="area", l_min=0.2, l_max=0.1))
    assert e.value.field == "params.l_min" and http_status(e.value)[0] == 422
    with pytest.raises(SlicingError) as e:
        slice_mesh(cyl, SliceParams(layer_mm=0.0))
    assert e.value.field == "params.layer_mm"
    with pytest.raises(SlicingError):
        slice_mesh(cyl, SliceParams(mode="bogus"))


def test_open_mesh_refused_or_repaired():
    box = trimesh.creation.box((2, 2, 2))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    with pytest.raises(MeshError) as e:
        slice_mesh(open_box, SliceParams(repair=False))
    assert "watertight" in e.value.message and e.value.field == "mesh"
    res = slice_mesh(open_box, SliceParams(layer_mm=0.5))
    assert any("filled holes" in r for r in res.repairs)
    assert res.layers[0].area == pytest.approx(4.0)
    cyl = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=32)
    top = cyl.triangles_center[:, 2] > 0.49
    uncapped = trimesh.Trimesh(cyl.vertices, cyl.faces[~top], process=False)
    res = slice_mesh(uncapped, SliceParams(layer_mm=0.5))   # a 32-gon hole: filled flat (a fan)
    assert res.volume == pytest.approx(polygon_area(1.0, 32) * 1.0, rel=1e-9)
    assert any("filled holes: 1 (32 open edges" in r for r in res.repairs)
    with pytest.raises(MeshError) as e:                       # unless holes that large may not be filled
        slice_mesh(uncapped, SliceParams(layer_mm=0.5, max_hole_mm=5.0))
    assert e.value.value["largest_hole_mm"] == pytest.approx(32 * 2 * math.sin(math.pi / 32), abs=1e-4)
    assert "max_hole_mm" in e.value.message


def test_overlapping_shells_repaired_or_refused():
    a = trimesh.creation.box((2, 2, 2))
    b = trimesh.creation.box((2, 2, 2))
    b.apply_translation((1.0, 0, 0))
    both = trimesh.util.concatenate([a, b])
    with pytest.raises(MeshError) as e:
        slice_mesh(both, SliceParams(repair=False))
    assert "self-intersecting" in e.value.message
    res = slice_mesh(both, SliceParams(layer_mm=0.5))
    assert res.layers[0].area == pytest.approx(6.0)   # union 3 x 2
    assert any("overlapping" in r for r in res.repairs)


def test_layer_with_no_area_is_an_error():
    a = trimesh.creation.box((2, 2, 1))
    b = trimesh.creation.box((2, 2, 1))
    b.apply_translation((0, 0, 3.0))
    with pytest.raises(SlicingError) as e:
        slice_mesh(trimesh.util.concatenate([a, b]), SliceParams(layer_mm=0.4))
    assert "no area" in e.value.message


def test_inverted_mesh_is_fixed_or_refused():
    box = trimesh.creation.box((1, 1, 1))
    box.invert()
    assert box.volume < 0
    with pytest.raises(MeshError):
        slice_mesh(box, SliceParams(repair=False))
    res = slice_mesh(box, SliceParams(layer_mm=0.25))
    assert res.layers[0].area == pytest.approx(1.0)
    assert np.all(res.thicknesses > 0)
