"""A print that opens a net the file connects (generated KiCad board): a dropped zero-length
track that joined two tracks, and a pour neck narrower than the nozzle's line, are found with
the gap and where it is, computed from the board's numbers; what the file itself leaves
apart (a net joined on another layer) is no open."""

from __future__ import annotations

import pytest
from shapely.geometry import LineString, Point

from app.circuits.formats import read_layout
from app.circuits.nets import Copper, area_polygon, trace_copper
from app.circuits.opens import NetOpenError, check_opens, curve_points, fill_coverage, find_opens
from app.platform.problems import http_status
from tests.circuits.boards import OPENS, open_board

LINE = 0.2


def _printed(layout, line=LINE):
    """The printed copper (traces at max(width, line), fills as their beads cover them) and the
    source's pieces as indices into it (traces, then pads, then areas: the layout's order)."""
    copper = [Copper("trace", t.source.entity, t.source.net, trace_copper(curve_points(t.curve), max(t.width_mm, line)))
              for t in layout.traces]
    copper += [Copper("pad", p.name, p.source.net, fill_coverage(p.exterior, [], line)) for p in layout.pads]
    copper += [Copper("area", a.source.entity, a.source.net, fill_coverage(a.exterior, a.holes, line))
               for a in layout.areas]
    n_t, n_p = len(layout.traces), len(layout.pads)
    pieces = [list(c.traces) + [n_t + k for k in c.pads] + [n_t + n_p + k for k in c.areas] for c in layout.connections]
    return copper, pieces


def test_the_source_connections_are_the_files():
    layout = read_layout(open_board().encode(), "b.kicad_pcb")
    assert any("zero-length" in n for n in layout.notes) and len(layout.dropped) == 1
    by_net = {c.net: c for c in layout.connections}
    assert set(by_net) == {"SIG", "GND"}                       # VCC's tracks are two pieces of one track each
    assert len(by_net["SIG"].traces) == 2 and len(by_net["GND"].pads) == 2 and len(by_net["GND"].areas) == 1
    # without the dot the file itself leaves SIG apart: nothing to hold the print to
    apart = read_layout(open_board(dot=False).encode(), "b.kicad_pcb")
    assert {c.net for c in apart.connections} == {"GND"}


def test_a_dropped_dot_and_a_narrow_pour_neck_open_their_nets():
    layout = read_layout(open_board().encode(), "b.kicad_pcb")
    opens = {o.net: o for o in find_opens(*_printed(layout))}
    assert set(opens) == set(OPENS)
    for net, (gap, at) in OPENS.items():
        # polygonal round caps sit inside the true circles: the gap is at most a few um wider
        assert opens[net].gap_mm == pytest.approx(gap, abs=5e-3), net
        assert Point(opens[net].at_mm).distance(LineString([at[:2], at[2:]])) <= 5e-3, net
    assert "piece" in opens["GND"].items[0] and "zone" in opens["GND"].items[1]
    with pytest.raises(NetOpenError) as info:
        check_opens(*_printed(layout), field="params.import_id")
    assert http_status(info.value)[0] == 422 and info.value.value["nets_open"] == 2
    assert "open net" in info.value.message


def test_a_neck_wider_than_the_line_and_a_finer_line_print_connected():
    wide = read_layout(open_board(neck_mm=0.5, dot=False).encode(), "b.kicad_pcb")
    copper, pieces = _printed(wide)
    assert find_opens(copper, pieces) == [] and check_opens(copper, pieces) == 1
    # a 0.05 mm line fills the 0.1 mm neck
    fine = read_layout(open_board(dot=False).encode(), "b.kicad_pcb")
    assert find_opens(*_printed(fine, line=0.05)) == []


def test_the_fill_coverage_is_the_outline_less_its_necks():
    layout = read_layout(open_board().encode(), "b.kicad_pcb")
    (pour,) = layout.areas
    drawn = area_polygon(pour.exterior, pour.holes)
    assert drawn.area == pytest.approx(50 + 0.1)
    covered = fill_coverage(pour.exterior, pour.holes, LINE)
    # two squares, each less its four corners' (1 - pi/4) r^2 (r = half the line)
    assert len(covered.geoms) == 2
    assert covered.area == pytest.approx(50 - 8 * (1 - 3.141592653589793 / 4) * 0.1 ** 2, abs=2e-4)
