"""The layer stack of a generated 4-layer KiCad board: each item keeps its copper layer and
side, the ``layer`` asked (top by default, bottom, inner<n>, a KiCad name) is the one printed,
every copper layer is reported with its counts (known from the board's numbers), and vias
join the layers from their first to their last."""

from __future__ import annotations

import pytest

from app.circuits.errors import CircuitFileError
from app.circuits.formats import read_layout
from app.circuits.layout import copper_side


def four_layers() -> str:
    """Tracks: 3 on F.Cu, 2 on In1.Cu, 1 on B.Cu; pads: one SMD on F.Cu, one through-hole on
    every layer; a zone on In2.Cu; a through via (F.Cu..B.Cu) and a blind via (F.Cu..In1.Cu)."""
    def seg(y, layer):
        return f'  (segment (start 0 {y}) (end 10 {y}) (width 0.25) (layer "{layer}") (net 1))'

    tracks = "\n".join([seg(1, "F.Cu"), seg(2, "F.Cu"), seg(3, "F.Cu"), seg(4, "In1.Cu"), seg(5, "In1.Cu"),
                        seg(6, "B.Cu")])
    return f"""(kicad_pcb (version 20221018) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (1 "In1.Cu" signal) (2 "In2.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))
  (net 0 "")
  (net 1 "SIG")
  (footprint "j" (layer "F.Cu") (at 20 5)
    (property "Reference" "J1")
    (pad "1" smd rect (at 0 0) (size 1 1) (layers "F.Cu") (net 1 "SIG"))
    (pad "2" thru_hole circle (at 3 0) (size 1.6 1.6) (drill 0.8) (layers "*.Cu") (net 1 "SIG")))
{tracks}
  (via (at 10 1) (size 0.8) (drill 0.4) (layers "F.Cu" "B.Cu") (net 1))
  (via blind (at 10 4) (size 0.6) (drill 0.3) (layers "F.Cu" "In1.Cu") (net 1))
  (zone (net 1) (net_name "SIG") (layer "In2.Cu") (hatch edge 0.5)
    (polygon (pts (xy 30 0) (xy 40 0) (xy 40 10) (xy 30 10)))
    (filled_polygon (layer "In2.Cu") (pts (xy 30 0) (xy 40 0) (xy 40 10) (xy 30 10))))
)
"""


STACK = {"F.Cu": ("top", 3, 2, 0, 2), "In1.Cu": ("inner", 2, 1, 0, 2), "In2.Cu": ("inner", 0, 1, 1, 1),
         "B.Cu": ("bottom", 1, 1, 0, 1)}


@pytest.mark.parametrize(("asked", "printed", "traces", "areas"), [
    (None, "F.Cu", 3, 0), ("top", "F.Cu", 3, 0), ("bottom", "B.Cu", 1, 0), ("inner1", "In1.Cu", 2, 0),
    ("In2.Cu", "In2.Cu", 0, 1)])
def test_the_layer_asked_is_printed_and_every_layer_is_reported(asked, printed, traces, areas):
    layout = read_layout(four_layers().encode(), "b.kicad_pcb", copper_layer=asked)
    assert len(layout.traces) == traces and len(layout.areas) == areas
    side = STACK[printed][0]
    for item in [*layout.traces, *layout.pads, *layout.areas]:
        assert item.source.layer == printed and item.source.to_dict()["side"] == side
    assert [row["layer"] for row in layout.stack] == list(STACK)
    for row in layout.stack:
        assert (row["side"], row["tracks"], row["pads"], row["zones"], row["vias"]) == STACK[row["layer"]]
        assert row["printed"] == (row["layer"] == printed)


def test_vias_join_the_layers_they_span():
    top = read_layout(four_layers().encode(), "b.kicad_pcb")
    assert sorted(v.layers for v in top.vias) == [("F.Cu", "B.Cu"), ("F.Cu", "In1.Cu")]
    assert [copper_side(n) for n in ("F.Cu", "In1.Cu", "B.Cu", "Copper,L1,Top", "Copper,L2,Inr", "Copper,L4,Bot",
                                     "CU")] == ["top", "inner", "bottom", "top", "inner", "bottom", ""]
    # the blind via does not reach In2.Cu: only the through via is an interconnect point there
    assert [v.layers for v in read_layout(four_layers().encode(), "b.kicad_pcb", copper_layer="In2.Cu").vias] == \
        [("F.Cu", "B.Cu")]


def test_a_layer_the_board_lacks_or_two_disagreeing_names_are_422s():
    with pytest.raises(CircuitFileError, match="In3.Cu"):
        read_layout(four_layers().encode(), "b.kicad_pcb", copper_layer="inner3")
    with pytest.raises(CircuitFileError, match="disagree") as info:
        read_layout(four_layers().encode(), "b.kicad_pcb", None, ["F.Cu"], copper_layer="bottom")
    assert info.value.field == "layer"
