"""Gerber X2 aperture functions decide what is printed (generated board): copper text
(NonConductor) is not a trace, the profile is the board's outline (not traces), a via's land
(ViaPad) is a via (not a pad to fill); conductors and pads are kept."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Polygon

from app.circuits.formats import read_layout
from tests.circuits.boards import PourBoard, gerber_x2, x2_graphics

BOARD = PourBoard()


def test_graphics_are_not_conductors():
    plain = read_layout(gerber_x2(BOARD).encode(), "top.gbr")
    layout = read_layout(gerber_x2(BOARD, extra=x2_graphics(BOARD)).encode(), "top.gbr")
    assert len(layout.traces) == len(plain.traces) == 1          # only the GND track
    assert len(layout.pads) == len(plain.pads) == 3              # the via land is not a pad
    assert len(layout.areas) == 1
    (via,) = layout.vias
    np.testing.assert_allclose(via.center, [12, 2])
    assert via.diameter_mm == pytest.approx(0.8, abs=1e-3) and via.net == "GND"
    (edge,) = layout.outline
    assert Polygon(edge).area == pytest.approx((BOARD.width + 2) * (BOARD.height + 4))
    assert any("NonConductor" in n for n in layout.notes) and any("Profile" in n for n in layout.notes)


def test_a_profile_file_is_the_outline():
    text = gerber_x2(BOARD, extra=x2_graphics(BOARD)).replace("Copper,L1,Top", "Profile,NP")
    layout = read_layout(text.encode(), "edge.gm1")
    assert layout.traces == [] and len(layout.outline) == 1
