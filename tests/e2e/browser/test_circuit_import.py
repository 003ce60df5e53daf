"""The circuit import on the traces page: preview (dry run: drawing, warnings, stretch; nothing
stored), then accept (traces stored with their source); an SVG through the server."""

from __future__ import annotations

from app.reference.s1 import s1_mesh
from tests.api.test_circuits import GERBER_MM

try:
    from playwright.sync_api import expect
except ImportError:  # the tests fail or skip in conftest; the module must still import
    expect = None  # type: ignore[assignment]

from tests.e2e.browser.conftest import screenshot


def test_preview_then_accept_a_gerber(page, served, tmp_path):
    api = served.api()
    stl = tmp_path / "s1.stl"
    stl.write_bytes(s1_mesh(grid_mm=1.0).export(file_type="stl"))
    part = api.post("/api/v1/parts", files={"file": ("s1.stl", stl.read_bytes())}).json()
    gerber = tmp_path / "top.gbr"
    gerber.write_text(GERBER_MM)
    page.goto(f"/traces.html?part={part['id']}")
    page.set_input_files("#circuit-file", str(gerber))
    page.fill("#circuit-origin-x", "5")
    page.fill("#circuit-origin-y", "10")
    page.click("#circuit-preview-button")                                   # project: exact curves
    page.wait_for_selector("#circuit-preview polyline", state="attached")
    page.select_option("#circuit-mapping", "wrap")
    page.click("#circuit-preview-button")
    # selectors: the pages' CSP forbids eval; the dry run also draws the 3-D preview (slow on a loaded box)
    page.wait_for_selector("#circuit-result table >> text=1.0000", timeout=90_000)
    assert page.locator("#circuit-preview polyline").count() == 2
    assert page.locator("#circuit-preview polygon").count() == 1            # the flashed pad
    assert "1.0000" in page.inner_text("#circuit-result table")             # stretch of a wrapped trace
    assert api.get(f"/api/v1/parts/{part['id']}/traces").json()["total"] == 0
    page.locator("#circuit-preview").scroll_into_view_if_needed()
    screenshot(page, "circuit-preview")
    page.click("#circuit-accept")
    # two traces + the pad's probe ring
    expect(page.locator("#traces-body tr[data-id]")).to_have_count(3, timeout=60_000)
    traces = api.get(f"/api/v1/parts/{part['id']}/traces").json()["items"]
    assert {t["source"].get("file", "top.gbr") for t in traces} == {"top.gbr"}
    svg = tmp_path / "art.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="60mm" height="40mm" viewBox="0 0 60 40">'
                   '<g transform="translate(10,5)"><path d="M 0 0 L 20 0" stroke-width="0.2"/></g></svg>')
    page.set_input_files("#import-file", str(svg))
    page.click("#import-button")
    expect(page.locator("#traces-body tr[data-id]")).to_have_count(4, timeout=60_000)
    items = api.get(f"/api/v1/parts/{part['id']}/traces").json()["items"]
    line = next(t for t in items if t["source"].get("file") == "art.svg")
    start = line["nominal"]["points"][0]
    assert abs(start[0] - 10.0) < 1e-6 and abs(start[1] - 35.0) < 1e-6      # y up from the page's bottom
    assert page.js_errors == []
