"""Circuit files are counted before they are expanded: bombs are refused in well under a
second of CPU, naming what was counted; the same constructions within the bounds are read whole."""

from __future__ import annotations

import time

import pytest

from app.circuits.budget import MAX_ITEMS, MAX_SHAPES
from app.circuits.errors import CircuitFileError
from app.circuits.formats import read_layout
from tests.circuits import bombs

BOMBS = {
    "block-bomb.dxf": (lambda: bombs.dxf_block_bomb(), "files", "block references counted"),
    "recursive.dxf": (bombs.dxf_recursive_block, "file", "inserts itself"),
    "use-bomb.svg": (lambda: bombs.svg_use_bomb(), "files", "<use> copies"),
    "long-path.svg": (lambda: bombs.svg_long_path(), "files", "path numbers"),
    "flashes.gbr": (lambda: bombs.gerber_flashes(), "files", "flashed pads"),
    "region.gbr": (lambda: bombs.gerber_region(), "files", "statements"),
    "region-110k.gbr": (lambda: bombs.gerber_region(110_000), "files", "region vertices"),
    "step-repeat.gbr": (lambda: bombs.gerber_step_repeat(), "files", "step-and-repeat"),
    "traces-and-pads.gbr": (lambda: bombs.gerber_traces_and_pads(MAX_SHAPES // 2 + 1, MAX_SHAPES // 2 + 1), "files",
                            "flashed pads"),
    "hits.drl": (lambda: bombs.excellon_hits(), "files", "lines"),
    "hits-past-shapes.drl": (lambda: bombs.excellon_hits(MAX_SHAPES + 1), "files", "drill hits"),
}


@pytest.mark.parametrize("name", sorted(BOMBS))
def test_a_bomb_is_refused_before_it_expands(name):
    make, field, counted = BOMBS[name]
    data = make().encode()
    started = time.thread_time()  # this thread's CPU: the work done, not the host's load
    with pytest.raises(CircuitFileError) as raised:
        read_layout(data, name)
    assert time.thread_time() - started < 1.0
    assert raised.value.field == field and counted in raised.value.message
    assert raised.value.value["file"] == name


@pytest.mark.parametrize("name, text, field", [
    ("huge.dxf", bombs.dxf_line(1e308), "coordinate"),
    ("far.dxf", bombs.dxf_line(1e6), "coordinate"),
    ("scale.svg", bombs.svg_scaled("1e300"), "coordinate"),
    ("radius.svg", bombs.svg_scaled("1", "1e300"), "coordinate"),
    ("aperture.gbr", bombs.gerber_flashes(3, "1e20"), "file"),
    ("wide.gbr", bombs.gerber_flashes(3, "1e5"), "coordinate"),
    ("tool.drl", bombs.excellon_hits(3, "1e20"), "file"),
    ("widetool.drl", bombs.excellon_hits(3, "300.0"), "width_mm"),
])
def test_numbers_past_any_board_are_a_422_naming_the_field(name, text, field):
    with pytest.raises(CircuitFileError) as raised:
        read_layout(text.encode(), name)
    assert raised.value.field == field and raised.value.value["file"] == name


def test_the_counts_are_exact_within_the_bounds():
    # 3 levels of 4 uses each: 4 ** 2 copies of the one-segment path
    assert len(read_layout(bombs.svg_use_bomb(levels=3, fan=4).encode(), "uses.svg").traces) == 16
    assert len(read_layout(bombs.dxf_block_bomb(levels=3, fan=4).encode(), "blocks.dxf").traces) == 16
    layout = read_layout(bombs.gerber_traces_and_pads(30, 20).encode(), "ok.gbr")
    assert (len(layout.traces), len(layout.pads)) == (30, 20)
    assert len(read_layout(bombs.excellon_hits(25).encode(), "ok.drl").vias) == 25  # drill hits are holes
    assert MAX_SHAPES < MAX_ITEMS
