"""Copper graphics and text of a KiCad board (generated): printed as copper areas (and lines
as traces) only when the import asks, their areas equal shapely's from the file's numbers;
otherwise reported.  Text: KiCad's stored outline when the file has one, else a TrueType
outline at the text's height, centred and turned where KiCad puts it."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import Point, Polygon, box

from app.circuits.formats import read_layout
from app.circuits.kicad_graphics import _font
from app.circuits.nets import area_polygon

FINE = 512          # quad segments of the shapely truth


def _board(extra: str = "") -> str:
    return f"""(kicad_pcb (version 20221018) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (37 "F.SilkS" user))
  (net 0 "")
  (segment (start 0 0) (end 5 0) (width 0.25) (layer "F.Cu") (net 0))
  (gr_poly (pts (xy 10 10) (xy 12 10) (xy 12 12) (xy 10 12)) (stroke (width 0) (type solid)) (fill solid)
    (layer "F.Cu"))
  (gr_rect (start 20 10) (end 24 12) (stroke (width 0.2) (type solid)) (fill none) (layer "F.Cu"))
  (gr_circle (center 30 10) (end 31 10) (stroke (width 0.2) (type solid)) (fill solid) (layer "F.Cu"))
  (gr_line (start 40 10) (end 45 10) (stroke (width 0.3) (type solid)) (layer "F.Cu"))
  (gr_rect (start 0 30) (end 4 32) (stroke (width 0.2) (type solid)) (fill solid) (layer "F.SilkS"))
  (footprint "logo" (layer "F.Cu") (at 50 20 90)
    (property "Reference" "G1")
    (fp_poly (pts (xy 1 0) (xy 2 0) (xy 2 1) (xy 1 1)) (stroke (width 0) (type solid)) (fill solid) (layer "F.Cu")))
{extra})
"""


def _truth() -> list[Polygon]:
    """The four copper shapes from the file's numbers (y up), by shapely."""
    poly = box(10, -12, 12, -10)
    rect = box(20, -12, 24, -10).exterior.buffer(0.1, quad_segs=FINE)
    disk = Point(30, -10).buffer(1.1, quad_segs=FINE)
    # the footprint's square, local (1..2, 0..1) KiCad = (1..2, -1..0) y up, turned 90 deg about (50, -20)
    logo = shapely.affinity.translate(shapely.affinity.rotate(box(1, -1, 2, 0), 90, origin=(0, 0)), 50, -20)
    return [poly, rect, disk, logo]


def test_graphics_are_reported_not_printed_by_default():
    layout = read_layout(_board().encode(), "g.kicad_pcb")
    assert layout.areas == [] and len(layout.traces) == 1
    (skipped,) = layout.skipped
    assert "5 copper graphic(s) and 0 copper text(s) on F.Cu not printed" in skipped


def test_graphics_are_copper_areas_when_asked():
    layout = read_layout(_board().encode(), "g.kicad_pcb", graphics=True)
    shapes = [area_polygon(a.exterior, a.holes) for a in layout.areas]
    assert len(shapes) == 4 and not layout.skipped
    for want in _truth():
        (got,) = [s for s in shapes if s.intersects(want.representative_point())]
        assert got.area == pytest.approx(want.area, abs=1e-3 * want.length)
        assert got.symmetric_difference(want).area <= 1e-3 * want.length
    ring = next(a for a in layout.areas if a.holes)           # the stroked rectangle: one hole
    assert Polygon(ring.holes[0]).area == pytest.approx(3.8 * 1.8, abs=1e-9)
    (line,) = [t for t in layout.traces if t.source.entity.startswith("gr_line")]
    assert line.width_mm == 0.3 and line.curve.length == pytest.approx(5.0)


def test_text_with_kicads_outline_is_that_outline():
    cached = """  (gr_text "L" (at 60 40) (layer "F.Cu") (effects (font (face "Arial") (size 2 2)))
    (render_cache "L" 0 (polygon (pts (xy 59 39) (xy 59.5 39) (xy 59.5 40.5) (xy 61 40.5) (xy 61 41) (xy 59 41)))))"""
    layout = read_layout(_board(cached).encode(), "g.kicad_pcb", graphics=True)
    (text,) = [a for a in layout.areas if "gr_text" in a.source.entity]
    want = Polygon([(59, -39), (59.5, -39), (59.5, -40.5), (61, -40.5), (61, -41), (59, -41)])
    assert area_polygon(text.exterior, text.holes).symmetric_difference(want).area <= 1e-12


@pytest.mark.skipif(_font() is None, reason="no TrueType outline font on this machine: text is reported")
@pytest.mark.parametrize("angle", [0, 90])
def test_text_in_an_outline_font_sits_where_kicad_puts_it(angle):
    text = f'  (gr_text "TEST" (at 60 40 {angle}) (layer "F.Cu") (effects (font (size 1.5 1.5) (thickness 0.3))))'
    layout = read_layout(_board(text).encode(), "g.kicad_pcb", graphics=True)
    letters = [a for a in layout.areas if "gr_text" in a.source.entity]
    assert len(letters) == 4 and all(not a.holes for a in letters)       # T, E, S, T: no counters
    glyphs = shapely.union_all([area_polygon(a.exterior, a.holes) for a in letters])
    x0, y0, x1, y1 = glyphs.bounds
    tall = (y1 - y0) if angle == 0 else (x1 - x0)
    assert tall == pytest.approx(1.5, rel=0.04)                          # the cap height (S overshoots ~2 %)
    np.testing.assert_allclose([(x0 + x1) / 2, (y0 + y1) / 2], [60, -40], atol=0.05)   # centred on its at
    wide = (x1 - x0) if angle == 0 else (y1 - y0)
    assert 3 * 1.5 * 0.6 < wide < 4 * 1.5                                # four letters about 0.6-1 high wide


def test_text_without_a_font_is_reported(monkeypatch):
    import app.circuits.kicad_graphics as g

    monkeypatch.setattr(g, "FONTS", ("no-such-font.ttf",))
    monkeypatch.setattr(g, "_font", lambda names=("no-such-font.ttf",): None)
    text = '  (gr_text "TEST" (at 60 40) (layer "F.Cu") (effects (font (size 1.5 1.5))))'
    layout = read_layout(_board(text).encode(), "g.kicad_pcb", graphics=True)
    assert not [a for a in layout.areas if "gr_text" in a.source.entity]
    (skipped,) = layout.skipped
    assert "'TEST'" in skipped and "no outline font" in skipped
