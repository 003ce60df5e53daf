"""Boards generated for the tests (no real board files are shipped): Gerber X2 and KiCad text
written from plain geometry, so that every count, area and net is known independently.

A *pour board*: a ground pour (net GND) over a W x H rectangle with one square clearance hole
around each other-net pad, the pads as round flashes (nets VCC, SIG) and one GND trace.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Gerber 4.6 mm coordinates: 1 unit = 1 nm
_NM = 1_000_000


def _xy(x: float, y: float) -> str:
    return f"X{round(x * _NM)}Y{round(y * _NM)}"


@dataclass
class PourBoard:
    """The board's plain geometry (mm, y up): pour rectangle, pads (x, y, diameter, net),
    holes (x, y, side: squares centred on other-net pads) and GND traces ((x0, y0), (x1, y1), width)."""

    width: float = 20.0
    height: float = 10.0
    pads: list[tuple[float, float, float, str]] = field(default_factory=lambda: [
        (5.0, 5.0, 1.5, "VCC"), (15.0, 5.0, 1.5, "SIG"), (10.0, 8.0, 1.0, "GND")])
    hole_side: float = 3.0
    trace: tuple[tuple[float, float], tuple[float, float], float] = ((10.0, 8.0), (10.0, 12.0), 0.25)

    @property
    def holes(self) -> list[tuple[float, float, float]]:
        return [(x, y, self.hole_side) for x, y, _, net in self.pads if net != "GND"]

    def pour_area(self, with_holes: bool = True) -> float:
        """The pour's copper area (mm^2), computed from the numbers."""
        return self.width * self.height - (len(self.holes) * self.hole_side ** 2 if with_holes else 0.0)

    def fractured_outline(self, with_holes: bool = True) -> list[tuple[float, float]]:
        """The pour as ONE contour, each hole reached by a slit up from the bottom edge (as ECAD
        plotters write pours with holes): CCW outside, CW around each hole, closed."""
        w, h = self.width, self.height
        pts = [(0.0, 0.0)]
        for x, y, side in (sorted(self.holes) if with_holes else []):
            a = side / 2
            pts += [(x, 0.0), (x, y - a), (x - a, y - a), (x - a, y + a), (x + a, y + a), (x + a, y - a),
                    (x, y - a), (x, 0.0)]
        return pts + [(w, 0.0), (w, h), (0.0, h), (0.0, 0.0)]


def gerber_x2(board: PourBoard, *, with_holes: bool = True, nets: bool = True, extra: str = "") -> str:
    """The board's top copper as a Gerber X2 file (mm, 4.6), with %TO.N% nets when ``nets``."""
    out = ["G04 generated pour board*", "%TF.FileFunction,Copper,L1,Top*%", "%FSLAX46Y46*%", "%MOMM*%",
           "%TA.AperFunction,Conductor*%", f"%ADD10C,{board.trace[2]:.6f}*%", "%TD*%"]
    diameters = sorted({d for _, _, d, _ in board.pads})
    for k, d in enumerate(diameters):
        out += ["%TA.AperFunction,SMDPad,CuDef*%", f"%ADD{11 + k}C,{d:.6f}*%", "%TD*%"]

    def net(name: str) -> list[str]:
        return [f"%TO.N,{name}*%"] if nets else []

    out += net("GND") + ["G36*"]
    outline = board.fractured_outline(with_holes)
    out += [_xy(*outline[0]) + "D02*"] + [_xy(*p) + "D01*" for p in outline[1:]] + ["G37*", "%TD*%"]
    (x0, y0), (x1, y1), _ = board.trace
    out += net("GND") + ["D10*", "G01*", _xy(x0, y0) + "D02*", _xy(x1, y1) + "D01*", "%TD*%"]
    for x, y, d, n in board.pads:
        out += net(n) + [f"D{11 + diameters.index(d)}*", _xy(x, y) + "D03*", "%TD*%"]
    return "\n".join(out) + "\n" + extra + "M02*\n"


def kicad_board(board: PourBoard, *, with_fill: bool = True, version: int = 20221018,
                extra: str = "") -> str:
    """The board as a ``.kicad_pcb`` (KiCad 6+ s-expressions; KiCad's y axis points down, so
    every y is written negated): the pour as a zone whose filled polygon is the fractured
    outline (or, without ``with_fill``, the zone outline only), the pads in one footprint."""
    netnames = ["", *sorted({n for *_, n in board.pads})]
    number = {n: i for i, n in enumerate(netnames)}
    pads = "\n".join(
        f'    (pad "{k + 1}" smd circle (at {x} {-y}) (size {d} {d}) (layers "F.Cu") (net {number[n]} "{n}"))'
        for k, (x, y, d, n) in enumerate(board.pads))
    w, h = board.width, board.height
    zone_pts = " ".join(f"(xy {x} {-y})" for x, y in [(0, 0), (w, 0), (w, h), (0, h)])
    fill_pts = " ".join(f"(xy {x} {-y})" for x, y in board.fractured_outline()[:-1])
    fill = f'\n    (filled_polygon (layer "F.Cu") (pts {fill_pts}))' if with_fill else ""
    (x0, y0), (x1, y1), tw = board.trace
    nets = "\n".join(f'  (net {i} "{n}")' for i, n in enumerate(netnames))
    return f"""(kicad_pcb (version {version}) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))
{nets}
  (footprint "board" (layer "F.Cu") (at 0 0)
    (property "Reference" "U1")
{pads}
  )
  (segment (start {x0} {-y0}) (end {x1} {-y1}) (width {tw}) (layer "F.Cu") (net {number["GND"]}))
  (zone (net {number["GND"]}) (net_name "GND") (layer "F.Cu") (hatch edge 0.5)
    (connect_pads (clearance 0.5)) (min_thickness 0.25)
    (fill yes (thermal_gap 0.5) (thermal_bridge_width 0.5))
    (polygon (pts {zone_pts})){fill})
{extra})
"""


def hole_polygons(board: PourBoard) -> list[np.ndarray]:
    """The holes as (4, 2) squares (mm)."""
    return [np.array([[x - s / 2, y - s / 2], [x + s / 2, y - s / 2], [x + s / 2, y + s / 2], [x - s / 2, y + s / 2]])
            for x, y, s in board.holes]


def sliver_tracks(kind: str) -> str:
    """A 20 mm track broken by a piece shorter than the format's resolution (as real boards
    hold them): KiCad and Gerber 1 nm, DXF 1 um, between two ordinary segments."""
    tiny = 1e-6 if kind in ("kicad", "gerber") else 1e-3
    pts = [(10.0, 10.0), (20.0, 10.0), (20.0 + tiny, 10.0), (30.0, 10.0)]
    if kind == "kicad":
        segs = "\n".join(f'  (segment (start {a[0]:.6f} {-a[1]:.6f}) (end {b[0]:.6f} {-b[1]:.6f}) (width 0.25) '
                         f'(layer "F.Cu") (net 1))' for a, b in zip(pts, pts[1:]))
        return f"""(kicad_pcb (version 20221018) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal))
  (net 0 "")
  (net 1 "SIG")
{segs}
)
"""
    if kind == "gerber":
        draws = "\n".join(f"{_xy(*a)}D02*\n{_xy(*b)}D01*" for a, b in zip(pts, pts[1:]))
        return f"%FSLAX46Y46*%\n%MOMM*%\n%ADD10C,0.250000*%\nD10*\nG01*\n{draws}\nM02*\n"
    import io

    import ezdxf

    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    for a, b in zip(pts, pts[1:]):
        doc.modelspace().add_line(a, b, dxfattribs={"layer": "CU", "lineweight": 25})
    out = io.StringIO()
    doc.write(out)
    return out.getvalue()


#: the special pads of :func:`kicad_pads_board`: name -> (centre in KiCad's frame (y down), area mm^2)
SPECIAL_PADS = {
    "U2.T": ((40.0, 20.0), 2.0),                                             # trapezoid 2 x 1, delta 0.5
    "U2.C": ((45.0, 20.0), 4.0),                                             # custom: anchor + 2x2 polygon
    "U2.R": ((50.0, 20.0), 2.0 - 2 * (1 - np.pi / 4) * 0.25 ** 2 - 2 * 0.2 ** 2 / 2),   # 2 round, 2 chamfered
}


def kicad_pads_board(version: int = 20221018) -> str:
    """A board with the pads KiCad draws specially (a trapezoid, a custom pad, a chamfered
    round-rect), a bare mounting hole (NPTH), a via, a track and an Edge.Cuts outline
    (0..60 x 0..40 in KiCad's frame).  ``version`` < 20211014 writes KiCad 5's syntax
    (``module``, the reference as fp_text)."""
    kicad5 = version < 20211014
    head = "module" if kicad5 else "footprint"
    ref = '(fp_text reference "U2" (at 0 -3) (layer "F.SilkS"))' if kicad5 else '(property "Reference" "U2")'
    return f"""(kicad_pcb (version {version}) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))
  (net 0 "")
  (net 1 "SIG")
  ({head} "special" (layer "F.Cu") (at 40 20)
    {ref}
    (pad "T" smd trapezoid (at 0 0) (size 2 1) (rect_delta 0.5 0) (layers "F.Cu") (net 1 "SIG"))
    (pad "C" smd custom (at 5 0) (size 0.5 0.5) (layers "F.Cu") (net 1 "SIG")
      (options (clearance outline) (anchor circle))
      (primitives (gr_poly (pts (xy -1 -1) (xy 1 -1) (xy 1 1) (xy -1 1)) (width 0))))
    (pad "R" smd roundrect (at 10 0) (size 2 1) (layers "F.Cu") (roundrect_rratio 0.25)
      (chamfer_ratio 0.2) (chamfer top_left bottom_right) (net 1 "SIG"))
    (pad "" np_thru_hole circle (at 15 0) (size 4.3 4.3) (drill 4.3) (layers "*.Cu" "*.Mask"))
  )
  (segment (start 30 30) (end 45 30) (width 0.25) (layer "F.Cu") (net 1))
  (via (at 45 30) (size 0.8) (drill 0.4) (layers "F.Cu" "B.Cu") (net 1))
  (gr_line (start 0 0) (end 60 0) (layer "Edge.Cuts") (width 0.1))
  (gr_line (start 60 0) (end 60 40) (layer "Edge.Cuts") (width 0.1))
  (gr_line (start 60 40) (end 0 40) (layer "Edge.Cuts") (width 0.1))
  (gr_line (start 0 40) (end 0 0) (layer "Edge.Cuts") (width 0.1))
)
"""


def x2_graphics(board: PourBoard) -> str:
    """What KiCad's Gerber X2 plot adds to a copper layer that is no conductor: copper text
    (draws with aperture function NonConductor), the board profile (Profile draws around
    -1..W+1 x -1..H+3) and a via's land (a ViaPad flash at (12, 2), 0.8 mm)."""
    w, h = board.width + 1, board.height + 3
    profile = [(-1.0, -1.0), (w, -1.0), (w, h), (-1.0, h), (-1.0, -1.0)]
    lines = ["%TA.AperFunction,NonConductor*%", "%ADD50C,0.150000*%", "%TD*%",
             "%TA.AperFunction,Profile*%", "%ADD51C,0.100000*%", "%TD*%",
             "%TA.AperFunction,ViaPad*%", "%ADD52C,0.800000*%", "%TD*%",
             "D50*", _xy(2, 2) + "D02*", _xy(3, 3) + "D01*", _xy(3, 2) + "D01*",
             "D51*", _xy(*profile[0]) + "D02*"] + [_xy(*p) + "D01*" for p in profile[1:]]
    lines += ["%TO.N,GND*%", "D52*", _xy(12, 2) + "D03*", "%TD*%"]
    return "\n".join(lines) + "\n"


#: :func:`open_board`'s two opens when printed with a 0.2 mm line: net -> (gap mm, where its
#: middle lies (a segment (x0, y0, x1, y1), y up: the pour's gap is as wide as the squares' facing sides))
OPENS = {"SIG": (0.15, (20.2, -10.0, 20.2, -10.0)), "GND": (1.0, (45.5, -10.0, 45.5, -5.0))}


def open_board(*, neck_mm: float = 0.1, dot: bool = True) -> str:
    """A KiCad board whose print opens two nets the file connects: SIG's two tracks (0.25 mm,
    ending at x = 20 and 20.4) meet only through a zero-length track at x = 20.2, 0.5 mm wide
    (a dot the import drops: a 0.15 mm gap between the track ends' caps); GND's pour is two
    5 x 5 mm squares (x 40..45 and 46..51, y 5..10) joined by a neck ``neck_mm`` wide and 1 mm
    long (narrower than a 0.2 mm line: its fill leaves a 1 mm gap), with a GND pad on each
    square.  VCC's two tracks are apart in the file already (joined on another layer): no open."""
    n0, n1 = 7.5 - neck_mm / 2, 7.5 + neck_mm / 2
    ring = [(40, 5), (45, 5), (45, n0), (46, n0), (46, 5), (51, 5), (51, 10), (46, 10), (46, n1), (45, n1),
            (45, 10), (40, 10)]
    pts = " ".join(f"(xy {x} {y})" for x, y in ring)
    segs = [((10, 10), (20, 10), 0.25, 1), ((20.4, 10), (30, 10), 0.25, 1), ((53, 10), (55, 10), 0.25, 3),
            ((57, 10), (59, 10), 0.25, 3)]
    if dot:
        segs.append(((20.2, 10), (20.2, 10), 0.5, 1))
    tracks = "\n".join(f'  (segment (start {a[0]} {a[1]}) (end {b[0]} {b[1]}) (width {w}) (layer "F.Cu") (net {n}))'
                       for a, b, w, n in segs)
    return f"""(kicad_pcb (version 20221018) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))
  (net 0 "")
  (net 1 "SIG")
  (net 2 "GND")
  (net 3 "VCC")
  (footprint "pads" (layer "F.Cu") (at 0 0)
    (property "Reference" "J1")
    (pad "1" smd circle (at 42.5 7.5) (size 1 1) (layers "F.Cu") (net 2 "GND"))
    (pad "2" smd circle (at 48.5 7.5) (size 1 1) (layers "F.Cu") (net 2 "GND"))
  )
{tracks}
  (zone (net 2) (net_name "GND") (layer "F.Cu") (hatch edge 0.5)
    (polygon (pts {pts}))
    (filled_polygon (layer "F.Cu") (pts {pts})))
)
"""


@dataclass(frozen=True)
class RowBoard:
    """A board of ``rows`` x ``per_row`` tracks: row r (net R<r>) runs along y = -r * pitch
    (KiCad's frame) from x = 0 in ``per_row`` segments ``seg`` mm long, with a round pad
    (``pad`` mm) at every ``pad_every``-th joint and at the row's end; tracks ``width`` mm; an
    Edge.Cuts rectangle 2 mm around.  Every count is known: tracks = rows x per_row, pads =
    rows x (per_row // pad_every + 1), one connected piece per net."""

    rows: int = 100
    per_row: int = 50
    seg: float = 3.0
    pitch: float = 1.15
    width: float = 0.25
    pad: float = 0.6
    pad_every: int = 5

    @property
    def pads(self) -> int:
        return self.rows * (self.per_row // self.pad_every + 1)

    @property
    def tracks(self) -> int:
        return self.rows * self.per_row

    @property
    def size(self) -> tuple[float, float]:
        return self.per_row * self.seg, (self.rows - 1) * self.pitch

    def kicad(self) -> str:
        nets = "\n".join(f'  (net {r + 1} "R{r}")' for r in range(self.rows))
        tracks, pads = [], []
        for r in range(self.rows):
            y = -r * self.pitch
            for k in range(self.per_row + 1):
                if k % self.pad_every == 0 or k == self.per_row:
                    pads.append(f'    (pad "{r}.{k}" smd circle (at {k * self.seg:.4f} {y:.4f}) (size {self.pad} '
                                f'{self.pad}) (layers "F.Cu") (net {r + 1} "R{r}"))')
                if k < self.per_row:
                    tracks.append(f'  (segment (start {k * self.seg:.4f} {y:.4f}) (end {(k + 1) * self.seg:.4f} '
                                  f'{y:.4f}) (width {self.width}) (layer "F.Cu") (net {r + 1}))')
        w, h = self.size
        edge = [(-2, 2), (w + 2, 2), (w + 2, -h - 2), (-2, -h - 2)]
        edges = "\n".join(f'  (gr_line (start {a[0]} {a[1]}) (end {b[0]} {b[1]}) (layer "Edge.Cuts") (width 0.1))'
                          for a, b in zip(edge, edge[1:] + edge[:1]))
        return (f'(kicad_pcb (version 20221018) (generator pcbnew)\n  (general (thickness 1.6))\n'
                f'  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))\n  (net 0 "")\n{nets}\n'
                f'  (footprint "rows" (layer "F.Cu") (at 0 0)\n    (property "Reference" "J1")\n'
                + "\n".join(pads) + "\n  )\n" + "\n".join(tracks) + "\n" + edges + "\n)\n")


# One GND segment and a connector whose two mounting pads share the number "MP" (their probe
# rings must still get different names).
USB_PADS_BOARD = """(kicad_pcb (version 20221018) (generator pcbnew)
  (general (thickness 1.6))
  (layers (0 "F.Cu" signal) (31 "B.Cu" signal) (44 "Edge.Cuts" user))
  (net 0 "")
  (net 1 "GND")
  (footprint "USB_C" (layer "F.Cu") (at 10 -10)
    (property "Reference" "J1")
    (pad "MP" smd rect (at -3 0) (size 1.2 1.2) (layers "F.Cu") (net 1 "GND"))
    (pad "MP" smd rect (at 3 0) (size 1.2 1.2) (layers "F.Cu") (net 1 "GND"))
    (pad "1" smd rect (at 0 0) (size 1.2 1.2) (layers "F.Cu") (net 1 "GND"))
  )
  (segment (start 7 10) (end 13 10) (width 0.25) (layer "F.Cu") (net 1))
)
"""
