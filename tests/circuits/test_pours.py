"""Pours keep their holes (Gerber X2 and KiCad, generated boards): the area with holes equals
an independent computation from the board's numbers, the fill never covers another net's
pad, and the netlist check finds exactly the shorts a solid pour would make."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Point, Polygon, box

from app.circuits.fills import fill_strokes
from app.circuits.formats import read_layout
from app.circuits.mapping import map_layout
from app.circuits.nets import Copper, NetShortError, area_polygon, check_nets, find_shorts, trace_copper
from app.circuits.placement import LayoutPlacement
from app.platform.problems import http_status
from tests.circuits.boards import PourBoard, gerber_x2, kicad_board

BOARD = PourBoard()
LINE = 0.2


def _expected_pour() -> Polygon:
    """The pour from the board's numbers: the rectangle less a square around each other-net pad."""
    holes = [box(x - s / 2, y - s / 2, x + s / 2, y + s / 2) for x, y, s in BOARD.holes]
    return box(0, 0, BOARD.width, BOARD.height).difference(shapely.union_all(holes))


def _copper(layout) -> list[Copper]:
    out = [Copper("pad", p.name or p.source.entity, p.source.net, Polygon(p.exterior)) for p in layout.pads]
    out += [Copper("area", a.source.entity, a.source.net, area_polygon(a.exterior, a.holes)) for a in layout.areas]
    out += [Copper("trace", t.source.entity, t.source.net,
                   trace_copper(t.curve.evaluate(np.linspace(*t.curve.domain, 50)), t.width_mm))
            for t in layout.traces]
    return out


@pytest.mark.parametrize(("name", "text"), [("top.gbr", gerber_x2(BOARD)), ("board.kicad_pcb", kicad_board(BOARD))])
def test_pour_keeps_its_holes_and_its_net(name, text):
    layout = read_layout(text.encode(), name)
    (pour,) = layout.areas
    assert pour.source.net == "GND" and len(pour.holes) == 2
    copper = area_polygon(pour.exterior, pour.holes)
    expected = _expected_pour()
    assert copper.area == pytest.approx(BOARD.pour_area(), abs=1e-9) == pytest.approx(expected.area, abs=1e-9)
    assert copper.symmetric_difference(expected).area <= 1e-9
    # mapping onto a flat part keeps the holes too (the stored and previewed form)
    flat = __import__("trimesh").creation.box(extents=[100, 100, 2])
    mapped = map_layout(layout, LayoutPlacement((-10.0, -5.0)), flat)
    (area,) = mapped.areas
    assert area.source["net"] == "GND" and len(area.holes_xy) == 2
    assert area_polygon(area.exterior_xy, area.holes_xy).area == pytest.approx(BOARD.pour_area(), abs=1e-9)


def test_the_fill_leaves_the_holes_and_other_nets_pads_empty():
    layout = read_layout(gerber_x2(BOARD).encode(), "top.gbr")
    (pour,) = layout.areas
    strokes = fill_strokes(pour.exterior, list(pour.holes), LINE)
    beads = shapely.union_all([LineString(s).buffer(LINE / 2) for s in strokes])
    expected = _expected_pour()
    assert beads.intersection(expected).area >= 0.98 * expected.area
    others = [Point(x, y).buffer(d / 2) for x, y, d, net in BOARD.pads if net != "GND"]
    covered = [p for p in others if beads.intersection(p).area > 1e-9]
    assert not covered                                   # a solid fill covers both (a short on each)


def test_netlist_check_passes_the_pour_with_holes_and_refuses_a_solid_one():
    good = read_layout(gerber_x2(BOARD).encode(), "top.gbr")
    assert find_shorts(_copper(good)) == []
    assert check_nets(_copper(good)) == 3
    solid = read_layout(gerber_x2(BOARD, with_holes=False).encode(), "top.gbr")
    shorts = find_shorts(_copper(solid))
    assert sorted(tuple(sorted(s.nets)) for s in shorts) == [("GND", "SIG"), ("GND", "VCC")]
    vcc = next(s for s in shorts if "VCC" in s.nets)
    assert Point(vcc.at_mm).distance(Point(5.0, 5.0)) <= 0.75 + 1e-9        # on the VCC pad
    with pytest.raises(NetShortError) as info:
        check_nets(_copper(solid), field="params.import_id")
    assert http_status(info.value)[0] == 422
    assert "GND" in info.value.message and "region 1" in info.value.message and "more" in info.value.message
    # the clearance: the holes leave 0.75 mm of air around each pad; asking for 1 mm is a violation
    assert {frozenset(s.nets) for s in find_shorts(_copper(good), clearance_mm=1.0)} == {
        frozenset({"GND", "VCC"}), frozenset({"GND", "SIG"})}
    assert find_shorts(_copper(good), clearance_mm=0.7) == []


def test_unnamed_copper_that_bridges_two_nets_is_a_short():
    """Without X2 nets on the pour, the pads' nets still show the bridge (the pour joins them)."""
    pads = [Copper("pad", "A", "VCC", Point(0, 0).buffer(0.5)), Copper("pad", "B", "SIG", Point(5, 0).buffer(0.5))]
    bridge = [Copper("trace", "t1", "", trace_copper(np.array([[0, 0], [2.5, 0]]), 0.2)),
              Copper("trace", "t2", "", trace_copper(np.array([[2.5, 0], [5, 0]]), 0.2))]
    (short,) = find_shorts(pads + bridge)
    assert set(short.nets) == {"VCC", "SIG"} and short.via in ("trace t1", "trace t2")
    assert find_shorts(pads + bridge[:1]) == []

