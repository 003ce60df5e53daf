"""Outline-stroke DXFs (generated with ezdxf, as ECAD plotters export copper in outline mode):
closed hairline loops (closed polylines, circles, LINE + ARC chains) are copper areas with
their holes by nesting, their areas equal to shapely's from the drawing's numbers; drawn
traces (with a width, or open) stay traces."""

from __future__ import annotations

import io

import ezdxf
import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Point, box

from app.circuits.formats import read_layout
from app.circuits.nets import area_polygon

#: arcs and circles are sampled within 1 um: an area within 1 um x its perimeter
CHORD = 0.001


def _dxf(build) -> bytes:
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    build(doc.modelspace())
    out = io.StringIO()
    doc.write(out)
    return out.getvalue().encode()


def _stadium(msp, a, b, width):
    """A track from a to b drawn as its outline: two LINEs and two ARCs (in a scrambled order,
    the second line reversed), as an outline plot draws it."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0]]) * width / 2
    angle = np.degrees(np.arctan2(d[1], d[0]))
    msp.add_arc(tuple(b), width / 2, angle - 90, angle + 90)
    msp.add_line(tuple(a + n), tuple(b + n))
    msp.add_arc(tuple(a), width / 2, angle + 90, angle + 270)
    msp.add_line(tuple(a - n), tuple(b - n))


def _board(msp):
    # a pour: a 10 x 5 rectangle (closed LWPOLYLINE) with a round hole (CIRCLE r 1.5) holding an
    # island (a 1 x 1 square of LINEs)
    msp.add_lwpolyline([(0, 0), (10, 0), (10, 5), (0, 5)], close=True)
    msp.add_circle((3, 2.5), 1.5)
    for p, q in [((2.5, 2), (3.5, 2)), ((3.5, 2), (3.5, 3)), ((3.5, 3), (2.5, 3)), ((2.5, 3), (2.5, 2))]:
        msp.add_line(p, q)
    # two tracks as outlines
    _stadium(msp, (20, 0), (30, 0), 0.5)
    _stadium(msp, (20, 5), (26, 8), 0.3)
    # drawn traces: a line with a lineweight, an open hairline, a closed polyline of constant width
    msp.add_line((40, 0), (50, 0), dxfattribs={"lineweight": 25})
    msp.add_line((40, 2), (50, 2))
    msp.add_lwpolyline([(40, 4), (45, 4), (45, 6)], close=True, dxfattribs={"const_width": 0.3})


def _expected():
    pour = box(0, 0, 10, 5).difference(Point(3, 2.5).buffer(1.5, quad_segs=512))
    island = box(2.5, 2, 3.5, 3)
    t1 = LineString([(20, 0), (30, 0)]).buffer(0.25, quad_segs=512)
    t2 = LineString([(20, 5), (26, 8)]).buffer(0.15, quad_segs=512)
    return [pour, island, t1, t2]


def test_closed_outline_loops_are_areas_with_holes():
    layout = read_layout(_dxf(_board), "cu.dxf")
    shapes = sorted((area_polygon(a.exterior, a.holes) for a in layout.areas), key=lambda g: -g.area)
    expected = sorted(_expected(), key=lambda g: -g.area)
    assert len(shapes) == 4
    assert [len(a.holes) for a in sorted(layout.areas, key=lambda a: -area_polygon(a.exterior, a.holes).area)] \
        == [1, 0, 0, 0]
    for got, want in zip(shapes, expected):
        assert got.area == pytest.approx(want.area, abs=CHORD * want.length)
        assert got.symmetric_difference(want).area <= CHORD * want.length
    # the three drawn traces stay traces
    assert len(layout.traces) == 3
    assert sorted(round(t.width_mm, 3) for t in layout.traces) == [0.0, 0.25, 0.3]
    assert any("outline loop" in n and "4 copper area" in n for n in layout.notes)


def test_a_plot_of_many_tracks_is_areas_not_traces():
    """500 tracks plotted as outlines (2,000 entities), crossing each other: no trace; the areas
    are the tracks' union, one per connected piece (shapely's union of the true stadiums)."""
    rng = np.random.default_rng(7)
    starts = rng.uniform(0, 80, (500, 2))
    ends = starts + rng.uniform(1, 5, (500, 2))

    def build(msp):
        for a, b in zip(starts, ends):
            _stadium(msp, a, b, 0.25)

    layout = read_layout(_dxf(build), "cu.dxf")
    tracks = [LineString([a, b]).buffer(0.125, quad_segs=512) for a, b in zip(starts, ends)]
    union = shapely.union_all(tracks)
    pieces = shapely.get_parts(union)
    assert len(layout.traces) == 0 and len(layout.areas) == len(pieces) < 500
    got = shapely.union_all([area_polygon(a.exterior, a.holes) for a in layout.areas])
    total = sum(area_polygon(a.exterior, a.holes).area for a in layout.areas)
    assert total == pytest.approx(got.area, abs=1e-9)                         # the areas do not overlap
    assert total == pytest.approx(union.area, abs=CHORD * sum(t.length for t in tracks))
    assert sum(len(a.holes) for a in layout.areas) == sum(len(p.interiors) for p in pieces)
