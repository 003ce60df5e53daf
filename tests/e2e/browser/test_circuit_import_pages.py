"""The circuit import's preview pages its warnings and trace rows: a board wider than the part
(6 rows of 40 tracks, 80 mm on a 60 mm part) gives 240 rows and a warning for every track off
the part; the page shows 50 of each at a time with "a-b of N" read against the API's own
totals of the same dry run, and Prev / Next walk every row exactly once."""

from __future__ import annotations

import json
import re

from app.reference.s1 import s1_mesh
from tests.circuits.boards import RowBoard
from tests.e2e.browser.conftest import screenshot

BOARD = RowBoard(rows=6, per_row=40, seg=2.0)
PAGE_ROWS = 50   # web/js/circuit_import.js


def _shown(page, which: str) -> tuple[int, int, int]:
    """(first, last, total) of the "<label> a–b of N" line of a paged list."""
    text = page.inner_text(f"#{which}-count")
    match = re.search(r"(\d+)–(\d+) of (\d+)", text)
    assert match, text
    return int(match[1]), int(match[2]), int(match[3])


def _walk(page, which: str, rows_selector: str) -> list[str]:
    """Every row's text, page after page (Next until it is disabled), checking the counts."""
    seen: list[str] = []
    while True:
        first, last, total = _shown(page, which)
        rows = page.locator(rows_selector).all_inner_texts()
        assert first == len(seen) + 1 and last - first + 1 == len(rows) <= PAGE_ROWS
        seen += rows
        if page.locator(f"#{which}-next").is_disabled():
            assert last == total
            return seen
        page.click(f"#{which}-next")
        page.wait_for_function("([id, n]) => document.getElementById(id).textContent.startsWith(n)",
                               arg=[f"{which}-count", _label(which) + f" {last + 1}–"])


def _label(which: str) -> str:
    return {"circuit-warnings": "warnings", "circuit-rows": "traces"}[which]


def test_the_preview_pages_warnings_and_rows(page, served, tmp_path):
    api = served.api()
    part = api.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=1.0).export(file_type="stl"))}).json()
    board = tmp_path / "rows.kicad_pcb"
    board.write_text(BOARD.kicad())
    truth = api.post(f"/api/v1/parts/{part['id']}/circuits:import", timeout=120,
                     files=[("files", ("rows.kicad_pcb", board.read_bytes()))],
                     data={"options": json.dumps({"dry_run": True})}).json()
    totals = truth["totals"]
    assert totals["traces"] == BOARD.tracks == 240 and totals["warnings"] > PAGE_ROWS, totals

    page.goto(f"/traces.html?part={part['id']}")
    # the import form is on the page before its part list has loaded: a preview sent earlier
    # finds no part chosen ("upload a part first") and never shows its rows
    page.wait_for_selector('body[data-ready="1"]')
    page.set_input_files("#circuit-file", str(board))
    page.click("#circuit-preview-button")
    page.wait_for_selector("#circuit-rows-count", timeout=120_000)
    assert _shown(page, "circuit-rows") == (1, PAGE_ROWS, totals["traces"])
    assert _shown(page, "circuit-warnings") == (1, PAGE_ROWS, totals["warnings"])
    assert page.locator("#circuit-rows-prev").is_disabled()
    on_part = sum(1 for t in truth["traces"] if t.get("trace"))
    assert 0 < on_part < totals["traces"]
    assert page.locator("#circuit-preview polyline").count() == on_part      # the top view draws every one, unpaged
    page.locator("#circuit-warnings-pages").scroll_into_view_if_needed()
    screenshot(page, "circuit-preview-pages")

    rows = _walk(page, "circuit-rows", "#circuit-rows-pages tbody tr")
    assert len(rows) == totals["traces"] and len(set(rows)) == totals["traces"]     # each row once
    warnings = _walk(page, "circuit-warnings", "#circuit-warnings li")
    assert len(warnings) == totals["warnings"]
    page.click("#circuit-rows-prev")
    first, last, _ = _shown(page, "circuit-rows")
    assert (first - 1) % PAGE_ROWS == 0 and first < totals["traces"]
    assert page.js_errors == []
