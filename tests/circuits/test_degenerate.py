"""Pieces shorter than the format's resolution (1 nm in KiCad and Gerber, 1 um in DXF) are
dropped with a note naming them, never a refusal of the board."""

from __future__ import annotations

import pytest

from app.circuits.formats import read_layout
from tests.circuits.boards import sliver_tracks

NAMES = {"kicad": "board.kicad_pcb", "gerber": "top.gbr", "dxf": "cu.dxf"}


@pytest.mark.parametrize("kind", ["kicad", "gerber", "dxf"])
def test_a_sliver_is_dropped_with_a_note(kind):
    layout = read_layout(sliver_tracks(kind).encode(), NAMES[kind])
    assert [round(t.curve.length, 9) for t in layout.traces] == [10.0, pytest.approx(10.0, abs=1e-3)]
    (note,) = [n for n in layout.notes if "shorter than" in n]
    assert "dropped" in note
