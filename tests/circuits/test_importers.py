"""Importers against hand-written or library-written fixtures: positions, lengths, widths
within 1 um of an independent computation; bad files name their line or entity."""

from __future__ import annotations

import io

import ezdxf
import numpy as np
import pytest

from app.circuits.errors import CircuitFileError
from app.circuits.formats import detect_format, read_layout
from app.platform.problems import http_status

UM = 1e-3

GERBER_INCH = """G04 hand-written, inch, 2.4 format*
%FSLAX24Y24*%
%MOIN*%
%ADD10C,0.0100*%
%ADD11R,0.0600X0.0400*%
%ADD12O,0.0800X0.0400*%
D10*
G01*
X0Y0D02*
X10000Y0D01*
G75*
G03X20000Y10000I0J10000D01*
G01*
D11*
X5000Y5000D03*
D12*
X15000Y5000D03*
G36*
X0Y20000D02*
X10000Y20000D01*
X10000Y30000D01*
X0Y30000D01*
X0Y20000D01*
G37*
M02*
"""

EXCELLON_MM = """M48
METRIC,TZ
T1C0.800
T2C1.000
%
T1
X10.0Y5.0
X12.5Y5.0
T2
X20.0Y7.5
M30
"""

KICAD = """(kicad_pcb (version 20221018) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))
  (net 0 "")
  (net 1 "VCC")
  (net 2 "SIG")
  (footprint "R_0805" (layer "F.Cu") (at 20 10 90)
    (property "Reference" "R1")
    (pad "1" smd rect (at -1 0 90) (size 1.2 1.4) (layers "F.Cu" "F.Paste" "F.Mask") (net 1 "VCC"))
    (pad "2" smd circle (at 1 0 90) (size 1 1) (layers "F.Cu" "F.Paste" "F.Mask") (net 2 "SIG"))
  )
  (segment (start 10 10) (end 30 10) (width 0.25) (layer "F.Cu") (net 1))
  (segment (start 0 0) (end 3 4) (width 0.5) (layer "B.Cu") (net 2))
  (arc (start 30 10) (mid 35 5) (end 30 0) (width 0.3) (layer "F.Cu") (net 2))
  (zone (net 1) (net_name "VCC") (layer "F.Cu") (hatch edge 0.5)
    (connect_pads (clearance 0.5)) (min_thickness 0.25)
    (fill yes (thermal_gap 0.5) (thermal_bridge_width 0.5))
    (polygon (pts (xy 40 0) (xy 50 0) (xy 50 5) (xy 40 5))))
)
"""


def test_gerber_inch_draws_arcs_flashes_and_regions_in_exact_mm():
    layout = read_layout(GERBER_INCH.encode(), "top.gbr")
    assert layout.units == "inch"
    line, arc = layout.traces
    assert line.width_mm == pytest.approx(0.254, abs=UM)             # 0.0100 in
    assert line.curve.length == pytest.approx(25.4, abs=UM)
    np.testing.assert_allclose(line.curve.evaluate([1.0])[0], [25.4, 0.0], atol=UM)
    # CCW quarter arc about (25.4, 25.4) from (25.4, 0) to (50.8, 25.4)
    assert arc.curve.length == pytest.approx(np.pi / 2 * 25.4, abs=UM)
    mid = arc.curve.evaluate([0.5])[0]
    assert np.linalg.norm(mid - [25.4, 25.4]) == pytest.approx(25.4, abs=UM)
    rect, oval = layout.pads
    np.testing.assert_allclose(rect.center, [12.7, 12.7], atol=UM)
    np.testing.assert_allclose(rect.exterior.max(0) - rect.exterior.min(0), [1.524, 1.016], atol=UM)
    assert oval.shape == "oval"
    np.testing.assert_allclose(oval.exterior.max(0) - oval.exterior.min(0), [2.032, 1.016], atol=UM)
    (area,) = layout.areas
    np.testing.assert_allclose(area.exterior.min(0), [0, 50.8], atol=UM)
    np.testing.assert_allclose(area.exterior.max(0), [25.4, 76.2], atol=UM)


def test_gerber_x2_net_attributes_become_nets():
    text = GERBER_INCH.replace("D10*\nG01*\n", "D10*\nG01*\n%TO.N,VCC*%\n", 1).replace("G75*", "%TD*%\nG75*")
    layout = read_layout(text.encode(), "top.gbr")
    assert [t.source.net for t in layout.traces] == ["VCC", ""]


def test_excellon_hits_are_holes_of_their_tool_not_pads():
    layout = read_layout(EXCELLON_MM.encode(), "holes.drl")
    assert layout.pads == [] and layout.traces == []
    assert [v.center.tolist() for v in layout.vias] == [[10, 5], [12.5, 5], [20, 7.5]]
    np.testing.assert_allclose([v.drill_mm for v in layout.vias], [0.8, 0.8, 1.0], atol=UM)


def test_kicad_tracks_pads_nets_and_layer_with_y_flipped():
    layout = read_layout(KICAD.encode(), "board.kicad_pcb", layers=["F.Cu"])
    seg, arc = layout.traces
    assert (seg.source.net, seg.width_mm, seg.source.layer) == ("VCC", 0.25, "F.Cu")
    np.testing.assert_allclose(seg.curve.evaluate([0.0, 1.0]), [[10, -10], [30, -10]], atol=UM)
    # the arc through (30,10) (35,5) (30,0) in KiCad's y-down frame: a half circle of radius 5
    assert arc.curve.length == pytest.approx(np.pi * 5, abs=UM)
    assert arc.source.net == "SIG" and arc.width_mm == 0.3
    p1, p2 = layout.pads
    # footprint at (20, 10) rotated 90 deg: local (-1, 0) -> (0, -1) in y-up, then (20, -10) + that
    np.testing.assert_allclose(p1.center, [20, -11], atol=UM)
    np.testing.assert_allclose(p2.center, [20, -9], atol=UM)
    # the rect pad 1.2 x 1.4 turned 90 deg: 1.4 wide in x, 1.2 in y
    np.testing.assert_allclose(p1.exterior.max(0) - p1.exterior.min(0), [1.4, 1.2], atol=UM)
    assert p1.source.net == "VCC" and p1.name == "R1.1"
    (zone,) = layout.areas                     # a copper pour (its outline: the file has no fill)
    assert zone.source.net == "VCC"
    np.testing.assert_allclose(zone.exterior.min(0), [40, -5], atol=UM)
    np.testing.assert_allclose(zone.exterior.max(0), [50, 0], atol=UM)
    back = read_layout(KICAD.encode(), "board.kicad_pcb", layers=["B.Cu"])
    assert len(back.traces) == 1 and back.traces[0].curve.length == pytest.approx(5.0, abs=UM)


def _dxf(units: int) -> str:
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = units
    msp = doc.modelspace()
    msp.add_line((0, 0), (1, 0), dxfattribs={"layer": "CU", "lineweight": 25})
    msp.add_lwpolyline([(0, 0, 0, 0, 0.5), (1, 0, 0, 0, 0), (1, 1, 0, 0, 0)], format="xyseb",
                       dxfattribs={"layer": "CU", "const_width": 0.01})
    msp.add_circle((2, 2), 0.5, dxfattribs={"layer": "CU"})
    msp.add_arc((3, 3), 1, 0, 90, dxfattribs={"layer": "CU"})
    msp.add_open_spline([(0, 0), (1, 2), (3, 2), (4, 0)], degree=3, dxfattribs={"layer": "CU"})
    msp.add_line((0, 5), (1, 5), dxfattribs={"layer": "SILK"})
    inner = doc.blocks.new("B")
    inner.add_line((0, 0), (1, 0))
    outer = doc.blocks.new("C")
    outer.add_blockref("B", (0, 1), dxfattribs={"rotation": 90})
    msp.add_blockref("C", (10, 0), dxfattribs={"layer": "CU", "xscale": 2, "yscale": 2})
    out = io.StringIO()
    doc.write(out)
    return out.getvalue()


def test_dxf_inch_lines_bulges_circles_arcs_splines_and_nested_blocks():
    layout = read_layout(_dxf(1).encode(), "a.dxf", layers=["CU"])
    assert layout.units == "inch" and set(layout.layers) == {"CU", "SILK"}
    line, poly, circle, arc, spline, nested = layout.traces
    assert line.curve.length == pytest.approx(25.4, abs=UM) and line.width_mm == 0.25
    # bulge 0.5: sweep 4 atan(0.5), radius = chord / (2 sin(sweep / 2)); then a 1-inch line
    sweep = 4 * np.arctan(0.5)
    radius = 1 / (2 * np.sin(sweep / 2))
    assert poly.curve.length == pytest.approx(25.4 * (radius * sweep + 1.0), abs=UM)
    assert poly.width_mm == pytest.approx(0.254, abs=UM)
    assert circle.curve.length == pytest.approx(2 * np.pi * 0.5 * 25.4, abs=UM)
    assert arc.curve.length == pytest.approx(np.pi / 2 * 25.4, abs=UM)
    np.testing.assert_allclose(arc.curve.evaluate([0.0, 1.0]), [[101.6, 76.2], [76.2, 101.6]], atol=UM)
    # the spline keeps its exact control points and degree (inch -> mm)
    assert spline.curve.degree == 3
    np.testing.assert_allclose(spline.curve.control_points, np.array([(0, 0), (1, 2), (3, 2), (4, 0)]) * 25.4,
                               atol=UM)
    # block B (line (0,0)-(1,0)) rotated 90 at (0,1) inside C, C scaled 2 at (10,0): (10,2)-(10,4) in
    np.testing.assert_allclose(nested.curve.evaluate([0.0, 1.0]), np.array([[10, 2], [10, 4]]) * 25.4, atol=UM)
    assert nested.source.layer == "CU"           # block entities on layer 0 take the INSERT's layer


def test_dxf_old_style_polyline_with_bulge():
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    poly = doc.modelspace().add_polyline2d([(0, 0), (10, 0), (10, 10)], dxfattribs={"layer": "CU"})
    poly.vertices[0].dxf.bulge = 1.0                       # a half circle of diameter 10 (CCW)
    out = io.StringIO()
    doc.write(out)
    (trace,) = read_layout(out.getvalue().encode(), "p.dxf").traces
    assert trace.curve.length == pytest.approx(np.pi * 5 + 10, abs=UM)
    # CCW from (0,0) to (10,0): the half circle passes below the chord, through (5, -5)
    samples = trace.curve.evaluate(np.linspace(*trace.curve.domain, 2001))
    assert samples[:, 1].min() == pytest.approx(-5.0, abs=UM)


def test_dxf_mm_units_are_mm():
    layout = read_layout(_dxf(4).encode(), "a.dxf", layers=["SILK"])
    assert layout.units == "mm" and layout.traces[0].curve.length == pytest.approx(1.0, abs=UM)


def test_svg_units_viewbox_and_nested_transforms():
    svg = b"""<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="50mm" viewBox="0 0 200 100">
      <g id="cu" transform="translate(10,10)"><g transform="scale(2,1)">
        <path id="p1" d="M 0 0 L 10 0 Q 20 0 20 10" stroke-width="0.5"/></g></g>
      <circle id="c" cx="50" cy="50" r="10"/></svg>"""
    layout = read_layout(svg, "art.svg", layers=["cu"])
    (path,) = layout.traces
    # user unit = 0.5 mm; (10,10) + diag(2,1) (x, y) in user units; y up from the page bottom (50 mm)
    start, end = path.curve.evaluate([path.curve.domain[0], path.curve.domain[1]])
    np.testing.assert_allclose(start, [5.0, 45.0], atol=UM)
    np.testing.assert_allclose(end, [25.0, 40.0], atol=UM)
    assert path.width_mm == pytest.approx(0.5 * 0.5 * np.sqrt(2), abs=UM)   # stroke scaled by sqrt(det)
    whole = read_layout(svg, "art.svg")
    circle = [t for t in whole.traces if "c" in t.source.entity.split()][0]
    assert circle.curve.length == pytest.approx(2 * np.pi * 5.0, abs=UM)


@pytest.mark.parametrize(("name", "data", "where"), [
    ("top.gbr", GERBER_INCH.replace("D11*", "D13*"), "line 14"),               # unknown aperture
    ("top.gbr", GERBER_INCH.rsplit("M02*", 1)[0], "line"),                     # truncated (no M02)
    ("holes.drl", EXCELLON_MM.replace("T2\n", "T3\n"), "line 9"),              # unknown tool
    ("board.kicad_pcb", KICAD[: KICAD.index("(arc")], "line 1"),                # truncated
])
def test_bad_files_name_their_line(name, data, where):
    with pytest.raises(CircuitFileError) as info:
        read_layout(data.encode(), name)
    assert where in info.value.message and http_status(info.value)[0] == 422


def test_wrong_layer_names_the_layer():
    with pytest.raises(CircuitFileError, match="In1.Cu"):
        read_layout(KICAD.encode(), "board.kicad_pcb", layers=["In1.Cu"])
    with pytest.raises(CircuitFileError, match="COPPER"):
        read_layout(_dxf(4).encode(), "a.dxf", layers=["COPPER"])


def test_truncated_dxf_names_its_last_line():
    text = _dxf(4)
    cut = text[: len(text) // 2]
    with pytest.raises(CircuitFileError, match=f"line {len(cut.splitlines())}"):
        read_layout(cut.encode(), "a.dxf")


def test_format_detection_by_name_and_content():
    assert detect_format("x.GBR", b"") == "gerber"
    assert detect_format("noext", KICAD.encode()) == "kicad"
    assert detect_format("noext", EXCELLON_MM.encode()) == "excellon"
    assert detect_format("noext", b"<svg xmlns='http://www.w3.org/2000/svg'/>") == "svg"
    with pytest.raises(CircuitFileError):
        detect_format("noext", b"hello")
