"""Small circuit files that expand into a great deal, and files with numbers past any board."""

from __future__ import annotations

import io

import ezdxf


def _dxf_text(doc) -> str:  # type: ignore[no-untyped-def]
    doc.header["$INSUNITS"] = 4  # mm
    stream = io.StringIO()
    doc.write(stream)
    return stream.getvalue()


def dxf_block_bomb(levels: int = 10, fan: int = 10) -> str:
    """A line in B0, each block B(i) inserting B(i-1) ``fan`` times; the model space inserts the
    last: fan ** levels lines from a few tens of KB."""
    doc = ezdxf.new()
    doc.blocks.new("B0").add_line((0, 0), (1, 0))
    for i in range(1, levels):
        block = doc.blocks.new(f"B{i}")
        for j in range(fan):
            block.add_blockref(f"B{i - 1}", (j * 2.0, 0))
    doc.modelspace().add_blockref(f"B{levels - 1}", (0, 0))
    return _dxf_text(doc)


def dxf_recursive_block() -> str:
    """A block that inserts itself."""
    doc = ezdxf.new()
    block = doc.blocks.new("SELF")
    block.add_line((0, 0), (1, 0))
    block.add_blockref("SELF", (1, 0))
    doc.modelspace().add_blockref("SELF", (0, 0))
    return _dxf_text(doc)


def dxf_line(x: float) -> str:
    """One LINE from (0, 0) to (x, 0)."""
    doc = ezdxf.new()
    doc.modelspace().add_line((0, 0), (x, 0))
    return _dxf_text(doc)


def svg_use_bomb(levels: int = 10, fan: int = 10) -> str:
    """Group g(i) uses g(i-1) ``fan`` times: fan ** levels paths from about 2 KB."""
    groups = ['<g id="g0"><path d="M0 0 L1 1" stroke="black"/></g>']
    for i in range(1, levels):
        groups.append(f'<g id="g{i}">' + "".join(f'<use xlink:href="#g{i - 1}"/>' for _ in range(fan)) + "</g>")
    return ('<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" width="100mm" '
            f'height="100mm" viewBox="0 0 100 100"><defs>{"".join(groups)}</defs>'
            f'<use xlink:href="#g{levels - 1}"/></svg>')


def svg_long_path(segments: int = 1_000_000) -> str:
    """One path of ``segments`` line segments (about 12 bytes each)."""
    d = "M0 0" + "".join(f" L{i % 90 + 1} {i % 37 + 1}" for i in range(segments))
    return f'<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm"><path d="{d}"/></svg>'


def svg_scaled(scale: str = "1e300", radius: str = "10") -> str:
    """A circle of ``radius`` in a group scaled by ``scale``."""
    return ('<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm">'
            f'<g transform="scale({scale})"><circle cx="5" cy="5" r="{radius}" stroke="black"/></g></svg>')


GERBER_HEAD = "%FSLAX46Y46*%\n%MOMM*%\n%ADD10C,0.200000*%\nD10*\n"


def gerber_flashes(n: int = 100_000, aperture: str = "0.2") -> str:
    """``n`` flashes of a circle of diameter ``aperture`` mm."""
    body = "".join(f"X{i * 1000}Y0D03*\n" for i in range(n))
    return f"%FSLAX46Y46*%\n%MOMM*%\n%ADD10C,{aperture}*%\nD10*\n{body}M02*\n"


def gerber_region(vertices: int = 1_000_000) -> str:
    """One region (G36/G37) of ``vertices`` vertices on a circle."""
    body = "".join(f"X{(i * 7919) % 50_000_000}Y{(i * 104729) % 50_000_000}D01*\n" for i in range(vertices))
    return GERBER_HEAD + "G36*\nX0Y0D02*\n" + body + "G37*\nM02*\n"


def gerber_step_repeat(x: int = 100_000, y: int = 100_000) -> str:
    """One flash repeated x * y times by a step-and-repeat block."""
    return GERBER_HEAD + f"%SRX{x}Y{y}I1.0J1.0*%\nX0Y0D03*\n%SR*%\nM02*\n"


def gerber_traces_and_pads(traces: int, pads: int) -> str:
    """``traces`` 1 mm draws and ``pads`` flashes."""
    draws = "".join(f"X0Y{i * 1000000}D02*\nX1000000Y{i * 1000000}D01*\n" for i in range(traces))
    flashes = "".join(f"X5000000Y{i * 1000000}D03*\n" for i in range(pads))
    return GERBER_HEAD + "G01*\n" + draws + flashes + "M02*\n"


def excellon_hits(n: int = 200_000, diameter: str = "0.8") -> str:
    """``n`` drill hits of one tool of ``diameter`` mm."""
    body = "".join(f"X{i % 1000}.0Y{i // 1000}.0\n" for i in range(n))
    return f"M48\nMETRIC,TZ\nT1C{diameter}\n%\nT1\n{body}M30\n"
