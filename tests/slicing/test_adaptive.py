"""Adaptive rules: the published area and multi-cavity behaviour, theta, our cusp rule."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from app.slicing import SliceParams, slice_mesh
from app.slicing.cavity import theta
from tests.slicing.conftest import cavity_block, stepped_block

SEED = dict(l_min=0.03, l_max=0.1, eps0=0.05)


def test_area_rule_thin_exactly_at_area_change():
    res = slice_mesh(stepped_block(step_z=3.0), SliceParams(mode="area", **SEED))
    t = res.thicknesses
    tops = np.array([lay.z_top for lay in res.layers])
    thin = t < 0.1 - 1e-9
    last = np.arange(len(t)) == len(t) - 1
    # thin layers only in the l_max approach to the step at z = 3 (or the capped top)
    near_step = (tops > 3.0 - 0.1) & (tops <= 3.0 + 1e-9)
    assert np.all((near_step | last)[thin])
    assert np.count_nonzero(thin & near_step) >= 1
    assert np.any(np.isclose(tops, 3.0))                   # a layer boundary on the step
    assert all("area change" in res.layers[k].reason for k in np.nonzero(thin & ~last)[0])
    assert np.count_nonzero(~thin) >= len(t) - 3
    assert tops[-1] == pytest.approx(6.0)


def test_area_rule_is_blind_to_cavity_band_but_cavity_rule_refines_it():
    mesh = cavity_block(6, band=(2.0, 4.0), radius=1.4)
    area = slice_mesh(mesh, SliceParams(mode="area", **SEED))
    cav = slice_mesh(mesh, SliceParams(mode="cavity", sigma0=0.05, mu0=0.005, mu1=0.167,
                                       **SEED))
    def inside_band(res):
        return [lay for lay in res.layers if 2.05 < lay.z_bottom and lay.z_top < 3.95]
    # area rule: constant area inside the band -> l_max; cavity rule: l_min there
    assert all(lay.thickness == pytest.approx(0.1) for lay in inside_band(area))
    assert all(lay.thickness == pytest.approx(0.03) for lay in inside_band(cav))
    assert all("multi-cavity" in lay.reason for lay in inside_band(cav))
    # far outside the band both use l_max
    for res in (area, cav):
        outside = [lay for lay in res.layers if lay.z_top < 1.8 or lay.z_bottom > 4.2]
        assert all(lay.thickness == pytest.approx(0.1) or lay.z_top == res.z_max
                   for lay in outside)
    assert len(cav.layers) > len(area.layers) + 40
    st = inside_band(cav)[0]
    assert st.inner_ring_count == 6
    assert st.mu == pytest.approx(st.sigma / 6)


def test_cavity_rule_ignores_sections_below_sigma0():
    mesh = cavity_block(6, band=(2.0, 4.0), radius=1.4)
    sigma = slice_mesh(mesh, SliceParams(layer_mm=0.5)).layers[6].sigma
    res = slice_mesh(mesh, SliceParams(mode="cavity", sigma0=sigma + 0.01, **SEED))
    band = [lay for lay in res.layers if 2.05 < lay.z_bottom and lay.z_top < 3.95]
    assert all(lay.thickness == pytest.approx(0.1) for lay in band)
    assert all(lay.mu == 0.0 for lay in band)


def test_theta_printed_formula_vs_indicator():
    # the printed int(ln(sigma - sigma0 + 55) / 4) flips at sigma0 - (55 - e^4), not sigma0
    flip = 0.45 - (55 - math.exp(4))
    assert theta(0.45, 0.45, "printed") == 1 and theta(0.45, 0.45, "indicator") == 1
    assert theta(0.30, 0.45, "printed") == 1 and theta(0.30, 0.45, "indicator") == 0
    assert theta(flip - 1e-6, 0.45, "printed") == 0
    assert theta(flip + 1e-6, 0.45, "printed") == 1
    assert theta(0.0, 0.45, "indicator") == 0


def test_step9_literal_reading_discards_area_refinement():
    keep = slice_mesh(stepped_block(), SliceParams(mode="cavity", **SEED))
    lit = slice_mesh(stepped_block(), SliceParams(mode="cavity", step9_resets_to_lmax=True,
                                                  **SEED))
    assert keep.thicknesses.min() < 0.1 - 1e-9
    # literal: a step that satisfied eps at 0.07 or 0.04 is reset to l_max
    assert np.count_nonzero(lit.thicknesses < 0.1 - 1e-9) <= \
        np.count_nonzero(keep.thicknesses < 0.1 - 1e-9)


def test_cusp_rule_matches_slope_and_snaps_to_flats():
    cone = trimesh.creation.cone(radius=10.0, height=10.0, sections=128)
    nz = np.abs(cone.face_normals[:, 2])
    nz = nz[nz < 0.99].max()   # slanted faces
    res = slice_mesh(cone, SliceParams(mode="cusp", cusp_mm=0.02, l_min=0.01, l_max=0.3))
    body = res.layers[:-1]
    assert all(lay.thickness == pytest.approx(0.02 / nz, rel=1e-6) for lay in body)
    cyl = trimesh.creation.cylinder(radius=3.0, height=5.0)
    res = slice_mesh(cyl, SliceParams(mode="cusp", cusp_mm=0.02, l_min=0.05, l_max=0.3))
    assert np.all(res.thicknesses[:-1] == pytest.approx(0.3))   # vertical wall: no cusp
    steps = slice_mesh(stepped_block(step_z=3.05), SliceParams(mode="cusp", l_min=0.05,
                                                               l_max=0.3))
    assert any(lay.z_top == pytest.approx(3.05) for lay in steps.layers)


def test_seed_modes_mid_sampling_keeps_the_rule():
    top = slice_mesh(stepped_block(), SliceParams(mode="area", seed_sample="top", **SEED))
    mid = slice_mesh(stepped_block(), SliceParams(mode="area", seed_sample="mid", **SEED))
    assert np.allclose(top.thicknesses, mid.thicknesses)          # same layer boundaries
    for lay in mid.layers:
        assert lay.z_sample == pytest.approx(0.5 * (lay.z_bottom + lay.z_top), abs=1e-4)
    for lay in top.layers:
        assert lay.z_sample == pytest.approx(min(lay.z_top, top.z_max - 1e-5))


def test_uniform_folds_a_float32_sliver_into_the_last_layer():
    import trimesh

    from app.slicing import SliceParams, slice_mesh

    box = trimesh.creation.box([10.0, 10.0, 0.05])
    box.apply_translation([0, 0, 0.025])
    box = trimesh.Trimesh(box.vertices.astype("float32").astype(float), box.faces)  # as read from STL
    result = slice_mesh(box, SliceParams(mode="uniform", layer_mm=0.025))
    assert [round(layer.thickness, 6) for layer in result.layers] == [0.025, 0.025]
