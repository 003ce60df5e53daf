"""KiCad boards as KiCad draws them (generated boards, KiCad 5 to 8 headers): trapezoid,
custom and chamfered round-rect pads with their areas from the numbers, a bare hole is not
copper, vias are read (not pads), the Edge.Cuts outline is the boundary (not traces), and a
board older than KiCad 5 is a 422 naming its version."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Polygon

from app.circuits.errors import CircuitFileError
from app.circuits.formats import read_layout
from app.platform.problems import http_status
from tests.circuits.boards import SPECIAL_PADS, PourBoard, kicad_board, kicad_pads_board

VERSIONS = {"KiCad 5": 20171130, "KiCad 6": 20211014, "KiCad 7": 20221018, "KiCad 8": 20240108}


@pytest.mark.parametrize("version", VERSIONS.values(), ids=VERSIONS.keys())
def test_special_pads_vias_and_outline(version):
    layout = read_layout(kicad_pads_board(version).encode(), "b.kicad_pcb")
    pads = {p.name: p for p in layout.pads}
    assert set(pads) == set(SPECIAL_PADS)                     # the NPTH mounting hole is not copper
    assert any("non-plated" in n for n in layout.notes)
    for name, ((x, y), area) in SPECIAL_PADS.items():
        np.testing.assert_allclose(pads[name].center, [x, -y], atol=1e-9)
        # polygons within 1 um of the arcs: the area within 1 um x the arcs' length (< 1e-3 mm^2)
        assert Polygon(pads[name].exterior).area == pytest.approx(area, abs=1e-3), name
    # the trapezoid: its side at -x is 1 + 0.5 tall, its side at +x 1 - 0.5
    ext = pads["U2.T"].exterior
    left, right = ext[ext[:, 0] < 40], ext[ext[:, 0] > 40]
    assert np.ptp(left[:, 1]) == pytest.approx(1.5) and np.ptp(right[:, 1]) == pytest.approx(0.5)
    assert len(layout.traces) == 1                            # the Edge.Cuts lines are not traces
    (via,) = layout.vias
    np.testing.assert_allclose(via.center, [45, -30])
    assert (via.diameter_mm, via.drill_mm, via.net) == (0.8, 0.4, "SIG")
    (edge,) = layout.outline
    assert Polygon(edge).area == pytest.approx(60 * 40)
    np.testing.assert_allclose(np.ptp(edge, axis=0), [60, 40])


@pytest.mark.parametrize("version", VERSIONS.values(), ids=VERSIONS.keys())
def test_pour_board_in_every_version(version):
    board = PourBoard()
    text = kicad_board(board, version=version)
    if version < 20211014:
        text = text.replace("(footprint", "(module")
    layout = read_layout(text.encode(), "b.kicad_pcb")
    assert len(layout.pads) == 3 and len(layout.traces) == 1
    (pour,) = layout.areas
    assert Polygon(pour.exterior, pour.holes).area == pytest.approx(board.pour_area())


@pytest.mark.parametrize("version", [3, 4, 20170000])
def test_a_board_older_than_kicad_5_is_a_422_naming_its_version(version):
    with pytest.raises(CircuitFileError) as info:
        read_layout(kicad_pads_board(version).encode(), "old.kicad_pcb")
    assert f"version {version}" in info.value.message and http_status(info.value)[0] == 422


def test_a_board_with_nothing_on_the_layer_is_a_422_not_an_empty_import():
    with pytest.raises(CircuitFileError, match="nothing to print on B.Cu"):
        read_layout(kicad_pads_board().encode(), "b.kicad_pcb", layers=["B.Cu"])
