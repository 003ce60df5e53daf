"""The circuit import's dry run seen in 3-D on the part before accepting (the page's own view:
draped traces, the warned ones in red, pad patches, probe rings), and the programs page: a
program uploaded, warped onto the probed part (progress, pieces, worst proved chord error,
the fixed split beside it, the warped program linked); a program printing outside the probed
area refused at submission naming its line."""

from __future__ import annotations

from PIL import Image

from app.reference.s1 import s1_mesh
from app.viewer.colors import PALETTE
from tests.api.test_circuits import GERBER_MM
from tests.e2e.browser.conftest import screenshot, screenshot_path
from tests.e2e.browser.pixels import save_view_panel, wait_for_view
from tests.e2e.browser.test_operator_flow import wait_job

TRACE_BLUE, WARNING_RED = PALETTE.nominal, PALETTE.dispense   # app/viewer/circuit_preview.py


def test_the_dry_run_in_3d_before_accepting(page, served, tmp_path):
    api = served.api()
    part = api.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=1.0).export(file_type="stl"))}).json()
    gerber = tmp_path / "top.gbr"
    # a third trace crossing the first: a spacing warning, drawn in red
    gerber.write_text(GERBER_MM.replace("X0Y5000000D02*",
                                        "X10000000Y-3000000D02*\nX10000000Y3000000D01*\nX0Y5000000D02*"))
    page.goto(f"/traces.html?part={part['id']}")
    page.set_input_files("#circuit-file", str(gerber))       # opens the page's 3-D view
    frame = page.frame_locator("#viewer-iframe")
    frame.locator(".mantine-Paper-root").first.wait_for(state="attached", timeout=60_000)   # the view is up
    page.fill("#circuit-origin-x", "5")
    page.fill("#circuit-origin-y", "10")
    page.click("#circuit-preview-button")
    page.wait_for_selector('#circuit-preview-3d[data-drawn="yes"]', state="attached")
    page.wait_for_selector("#circuit-preview polyline", state="attached")        # the top view is kept
    view_id = page.get_attribute("#viewer-panel", "data-view")
    scene = api.get("/api/v1/viewer/scene", params={"view_id": view_id}).json()
    assert scene["focus"]["part_id"] == part["id"] and scene["focus"]["preview"].startswith("cimp")
    nodes = scene["nodes"]
    assert len([n for n in nodes if n.startswith("/focus/traces/")]) == 3
    assert nodes["/focus/toolpaths/warnings/dispense"]["count"] > 0
    assert nodes["/focus/fields/pads"]["count"] > 0 and nodes["/focus/probes/pad_probe_rings/planned"]["count"] > 0
    assert api.get(f"/api/v1/parts/{part['id']}/traces").json()["total"] == 0          # nothing stored
    assert "warning" in page.inner_text("#circuit-result table")
    page.locator("#viewer-panel").scroll_into_view_if_needed()
    # the browser draws the preview: the slate part framed in the canvas, the draped traces in
    # their blue, the warned trace over them in red (unlit lines: their own RGB)
    counts, img = wait_for_view(page, lambda c: c.slate > 0.02 * c.total and c.exact[TRACE_BLUE] >= 20
                                and c.exact[WARNING_RED] >= 20, exact=(TRACE_BLUE, WARNING_RED))
    Image.fromarray(img).save(screenshot_path("circuit-preview-3d-canvas"))
    assert counts.slate > 0.02 * counts.total, f"the part is not on the canvas: {counts}"
    assert counts.exact[TRACE_BLUE] >= 20, f"no draped traces on the canvas: {counts}"
    assert counts.exact[WARNING_RED] >= 20, f"the warned trace is not drawn in red: {counts}"
    save_view_panel(page, screenshot_path("circuit-preview-3d"))
    assert page.js_errors == []


def test_the_programs_page_warps_onto_the_probed_part(page, served, tmp_path):
    api = served.api()
    part = api.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=1.0).export(file_type="stl"))}).json()
    fit = api.post("/api/v1/jobs", json={"kind": "surface_fit", "params": {
        "part_id": part["id"], "region": {"x": [5, 55], "y": [5, 35]}, "grid": [21, 13]}}).json()
    assert wait_job(api, fit["id"], timeout=120)["status"] == "succeeded"
    program = tmp_path / "lines.gcode"
    program.write_text("G21\nG90\nG0 X10 Y10\nM106\nG1 X50 Y12 F600\nG1 X50 Y30\nM107\n")
    page.goto("/programs.html")
    page.wait_for_selector("nav a.active >> text=Programs")
    page.set_input_files("#program-file", str(program))
    page.click("#program-upload-button")
    page.wait_for_selector('#programs-table tr[data-program] >> text=lines.gcode')
    page.select_option("#warp-surface", f"surface_fit:{fit['id']}")
    page.fill("#warp-standoff", "0.1")
    page.click("#warp-submit")
    page.wait_for_selector("#warp-figures", timeout=120_000)
    assert page.get_attribute("#warp-progress", "value") == "1"
    job_id = page.get_attribute("#warped-link", "title")  # the id on hover, the link says what it is
    job = api.get(f"/api/v1/jobs/{job_id}?include=result&include=artifacts").json()
    assert job["kind"] == "warp_program" and job["status"] == "succeeded"
    shown = page.inner_text('[data-figure="pieces"]')
    assert shown == str(job["result"]["pieces"]) and job["result"]["pieces"] > 2
    assert job["result"]["max_chord_bound_mm"] <= 0.002
    assert "µm" in page.inner_text('[data-figure="worst chord error (against the height model)"]')
    assert "µm" in page.inner_text('[data-figure="height model"]')
    # the model's own error beside the chord bound (the bound holds against the model only)
    assert "µm" in page.inner_text('[data-figure="height model error (cross-validated max)"]')
    assert page.locator("#warp-figures >> text=fixed 5.000 mm split").count() == 1
    screenshot(page, "programs-warp")

    outside = tmp_path / "outside.gcode"
    outside.write_text("G21\nG90\nG0 X10 Y10\nM106\nG1 X58 Y12 F600\nM107\n")
    page.set_input_files("#program-file", str(outside))
    page.click("#program-upload-button")
    page.wait_for_selector('#programs-table tr[data-program] >> text=outside.gcode')
    page.click("#warp-submit")
    page.wait_for_selector("#warp-refused")
    assert page.get_attribute("#warp-refused", "data-line") == "5"
    assert "x=58.0000" in page.inner_text("#warp-refused")
    assert page.js_errors == []


def test_the_programs_page_has_no_serious_accessibility_violations(page):
    from axe_playwright_python.sync_playwright import Axe

    page.goto("/programs.html")
    page.wait_for_selector('body[data-ready="1"]')
    violations = Axe().run(page).response["violations"]
    serious = [(v["id"], v["impact"], [n["target"] for n in v["nodes"]][:3]) for v in violations
               if v["impact"] in ("serious", "critical")]
    assert serious == [], serious
