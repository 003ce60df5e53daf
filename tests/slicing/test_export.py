"""SLC / CLI / JSON / SVG exports read back by independent parsers."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from shapely.geometry import Polygon

from app.slicing import SliceParams, slice_mesh
from app.slicing.errors import SlicingError
from app.slicing.export import SlcOptions, layer_svg, to_cli, to_json, to_slc
from tests.slicing.conftest import cavity_block
from tests.slicing.readers import read_cli, read_slc


@pytest.fixture(scope="module")
def adaptive():
    return slice_mesh(cavity_block(3), SliceParams(mode="cavity", l_min=0.05, l_max=0.2,
                                                    sigma0=0.02))


def _same_rings(lay, rings, tol):
    ours = [r for isl in lay.islands for r in isl.rings()]
    assert len(ours) == len(rings)
    for a, b in zip(ours, rings):
        assert np.allclose(b[0], b[-1])                       # closed in the file
        assert np.allclose(a, b[:-1], atol=tol)
        assert Polygon(b).area == pytest.approx(abs(Polygon(a).area), rel=1e-6)


def test_slc_round_trip(adaptive):
    exp = to_slc(adaptive)
    got = read_slc(exp.data)
    assert got["header"].startswith("-SLCVER 2.0 -UNIT MM")
    assert len(got["layers"]) == len(adaptive.layers)
    assert 1 <= len(got["table"]) <= 255
    for lay, (z, rings) in zip(adaptive.layers, got["layers"]):
        assert z == pytest.approx(lay.z_bottom, abs=1e-5)
        _same_rings(lay, rings, 1e-5)
        signs = [np.sign(Polygon(r).exterior.is_ccw - 0.5) for r in rings]
        assert signs[0] > 0 and all(s < 0 for s in signs[1:])  # outer CCW, holes CW
    assert got["end_z"] == pytest.approx(adaptive.z_max, abs=1e-5)
    # sampling table thicknesses match the layers they start
    zs = np.array([z for z, _ in got["layers"]] + [got["end_z"]])
    for min_z, thick, _, _ in got["table"]:
        k = int(np.argmin(np.abs(zs - min_z)))
        assert zs[k + 1] - zs[k] == pytest.approx(thick, abs=1e-5)


def test_slc_table_is_merged_to_255_entries_and_says_so():
    res = slice_mesh(cavity_block(2), SliceParams(mode="uniform", layer_mm=0.2))
    # fake alternating thicknesses: 600 runs
    import dataclasses
    layers, z = [], res.z_min
    for k in range(600):
        t = 0.01 if k % 2 else 0.0099
        layers.append(dataclasses.replace(res.layers[0], index=k, z_bottom=z, z_top=z + t))
        z += t
    fake = dataclasses.replace(res, layers=tuple(layers))
    exp = to_slc(fake, SlcOptions(quantum_mm=0.0001))
    assert len(exp.table) == 255 and any("merged" in n for n in exp.notes)
    got = read_slc(exp.data)
    assert len(got["layers"]) == 600
    exp2 = to_slc(fake, SlcOptions(quantum_mm=0.001))
    assert any("quantised" in n for n in exp2.notes) and len(exp2.table) <= 255
    # z comes from the running sum, rounded once: no drift (thickness-by-thickness rounding
    # would end 300 x 0.0001 = 0.03 mm above the true top)
    got2 = read_slc(exp2.data)
    true_tops = np.array([lay.z_bottom for lay in layers] + [layers[-1].z_top])
    read_z = np.array([z for z, _ in got2["layers"]] + [got2["end_z"]])
    assert np.max(np.abs(read_z - true_tops)) <= 0.0005 + 1e-6
    with pytest.raises(SlicingError):
        to_slc(fake, SlcOptions(quantum_mm=0.03))      # layers thinner than half the quantum


def test_cli_round_trip_with_hatches(adaptive):
    hatches = {0: np.array([[0.0, 1.0, 40.0, 1.0], [0.0, 2.0, 40.0, 2.0]])}
    got = read_cli(to_cli(adaptive, hatches=hatches))
    assert got["n_layers"] == len(adaptive.layers) == len(got["layers"])
    for lay, (z, polys, _h) in zip(adaptive.layers, got["layers"]):
        assert z == pytest.approx(lay.z_top, abs=1e-6)
        assert [d for d, _ in polys] == [1] + [0] * lay.inner_ring_count
        _same_rings(lay, [p for _, p in polys], 1e-6)
    assert np.allclose(got["layers"][0][2][0], hatches[0])


def test_json_and_svg(adaptive):
    doc = json.loads(to_json(adaptive))
    assert len(doc["layers"]) == len(adaptive.layers)
    lay = doc["layers"][12]
    assert lay["inner_rings"] == adaptive.layers[12].inner_ring_count
    assert Polygon(lay["islands"][0]["outer"], lay["islands"][0]["holes"]).area == \
        pytest.approx(adaptive.layers[12].area, rel=1e-6)
    svg = ET.fromstring(layer_svg(adaptive, 12, paths=[np.array([[0, 0], [1, 1]])]))
    assert svg.tag.endswith("svg")
    d = svg.find("{http://www.w3.org/2000/svg}path").get("d")
    assert d.count("M ") == adaptive.layers[12].ring_count
    with pytest.raises(SlicingError):
        layer_svg(adaptive, 10_000)
