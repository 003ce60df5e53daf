"""The toolpath preview in a real browser, as a slicer shows it: the part and the program in one
frame, the layer slider hiding the layers above k (read on the canvas's pixels), the legend of
move types in the view's colours, and each layer's z, height and time as the job computed them."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest
import trimesh
from PIL import Image

from app.viewer.preview_draw import MOVE_COLORS
from tests.e2e.browser.conftest import screenshot_path
from tests.e2e.browser.pixels import save_view_panel, view_image
from tests.e2e.browser.test_operator_flow import wait_job


@pytest.fixture(scope="module")
def toolpath(served) -> dict:
    """A 24 x 16 x 8 mm box sliced at 1 mm (8 layers), filled in dispense mode."""
    api = served.api()
    buffer = io.BytesIO()
    mesh = trimesh.creation.box(extents=(24, 16, 8))
    mesh.apply_translation([12, 8, 4])
    mesh.export(buffer, file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("preview-box.stl", buffer.getvalue())}).json()
    sliced = wait_job(api, api.post("/api/v1/jobs", json={"kind": "slice", "params": {
        "part_id": part["id"], "layer_mm": 1.0}}).json()["id"], 90)
    assert sliced["status"] == "succeeded", sliced
    job = wait_job(api, api.post("/api/v1/jobs", json={"kind": "toolpath", "params": {
        "slice_job_id": sliced["id"], "pattern": "raster", "mode": "dispense", "line_width_mm": 0.8}}).json()["id"], 90)
    assert job["status"] == "succeeded", job
    return job


def path_rows(img: np.ndarray) -> np.ndarray:
    """Image rows holding perimeter (orange) or infill (green) pixels: hue tests wide enough for
    the faint part drawn over them, narrow enough to exclude slate, grey travel and white."""
    rgb = img.astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    orange = (r > 150) & (r - g > 50) & (g - b > 40)
    green = (g > 110) & (g - r > 60) & (g - b > 30)
    return np.flatnonzero((orange | green).sum(axis=1) >= 3)


def wait_rows(page, check, timeout_ms: int = 60_000) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The path rows once ``check(rows)`` holds (software GL needs frames); the last either way."""
    waited = 0
    while True:   # the view's top below the sticky header (its green and red badges are no path)
        page.locator("#viewer-iframe").evaluate(
            "el => window.scrollTo(0, el.getBoundingClientRect().top + window.scrollY - 100)")
        rows = path_rows(view_image(page))
        if check(rows) or waited >= timeout_ms:
            return rows
        page.wait_for_timeout(500)
        waited += 500


@pytest.mark.timeout(900)
def test_the_toolpath_preview_hides_the_layers_above_the_slider(page, served, toolpath):
    layers = toolpath["result"]["layers"]
    page.goto(f"/jobs.html?job={toolpath['id']}")
    page.click("#open-3d")
    page.wait_for_selector("#preview-legend li[data-type='perimeter']")
    # the legend: the move types in the view's own colours, with their move counts
    legend = {li.get_attribute("data-type"): li for li in page.query_selector_all("#preview-legend li")}
    assert {"perimeter", "infill", "travel", "dispense_on", "dispense_off"} <= set(legend)
    assert legend["perimeter"].get_attribute("data-color") == "#%02x%02x%02x" % MOVE_COLORS["perimeter"]
    assert "perimeter" in legend["perimeter"].inner_text()
    # every layer's z, height and time as the job computed them, the top one current
    rows = page.query_selector_all("#preview-layers tbody tr")
    assert len(rows) == len(layers) == 8
    shift_z = toolpath["result"]["placement"]["shift_mm"][2]
    for row, layer in zip(rows, layers):
        cells = [c.inner_text() for c in row.query_selector_all("td")]
        assert cells[1] == f"{layer['z'] + shift_z:.3f} mm" and cells[2] == f"{layer['thickness']:.3f} mm"
    assert "current" in (rows[-1].get_attribute("class") or "")
    info = page.inner_text("#preview-layer-info")
    assert re.search(r"Layer 7 \(8 of 8\): z \d+\.\d{3} mm · height 1\.000 mm · time .*s", info), info
    # on the canvas: the whole stack first; at layer 1 the rows of the layers above are empty
    full = wait_rows(page, lambda r: len(r) > 40)
    assert len(full) > 40, "the program is not drawn"
    Image.fromarray(view_image(page)).save(screenshot_path("toolpath-preview-canvas"))
    page.locator("#preview-layer").fill("1")        # input + change, as a drag released on 1
    page.wait_for_selector("#preview-layer-info[data-layer='1']")
    assert "current" in (page.query_selector_all("#preview-layers tbody tr")[1].get_attribute("class") or "")
    assert "above" in (page.query_selector_all("#preview-layers tbody tr")[5].get_attribute("class") or "")
    shown = {li.get_attribute("data-type"): int(li.query_selector(".shown").inner_text())
             for li in page.query_selector_all("#preview-legend li")}
    assert 0 < shown["perimeter"] < int(legend["perimeter"].inner_text().split(" of ")[-1])
    low = wait_rows(page, lambda r: len(r) and r.min() > full.min() + 15)
    # the camera did not move: the top of the drawn path came down, 6 of 8 layers' rows are gone
    assert len(low) and low.min() > full.min() + 15, (full.min(), low.min() if len(low) else None)
    assert len(low) < len(full)
    page.set_viewport_size({"width": 1400, "height": 1500})         # the view, the legend and the layers
    save_view_panel(page, screenshot_path("toolpath-preview"))
    assert page.js_errors == []
    # the preview's slider, legend and table as axe-core reads them (the view's iframe aside)
    from axe_playwright_python.sync_playwright import Axe

    violations = Axe().run(page, context={"include": [["#preview-panel"]]}).response["violations"]
    serious = [(v["id"], [n["target"] for n in v["nodes"]][:3]) for v in violations
               if v["impact"] in ("serious", "critical")]
    assert serious == [], serious


def distance_to_path(point: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> float:
    """Shortest distance (mm) from ``point`` (3,) to the segments starts[i] -> ends[i] (m, 3)."""
    d = ends - starts
    length2 = np.maximum((d * d).sum(axis=1), 1e-18)
    t = np.clip(((point - starts) * d).sum(axis=1) / length2, 0.0, 1.0)
    return float(np.linalg.norm(starts + t[:, None] * d - point, axis=1).min())


@pytest.mark.timeout(900)
def test_the_machine_page_draws_the_head_on_the_path_while_printing(page, served, toolpath):
    from app.viewer.gcode_paths import parse_toolpath

    api = served.api()
    machine = api.post("/api/v1/machines", json={"name": "head-bench", "port": "mock://",
                                                 "mock": {"time_scale": 1.0}}).json()
    assert api.post(f"/api/v1/machines/{machine['id']}/connect").status_code == 200
    assert api.post(f"/api/v1/machines/{machine['id']}/home").status_code == 200
    text = api.get(f"/api/v1/jobs/{toolpath['id']}/artifacts/print.gcode").text
    moves = parse_toolpath(text)
    started = api.post(f"/api/v1/machines/{machine['id']}/print", json={"job_id": toolpath["id"],
                                                                        "artifact": "print.gcode"})
    assert started.status_code == 202, started.text
    try:
        page.goto("/machines.html")
        page.wait_for_selector(f'.machine-card[data-id="{machine["id"]}"] [data-state="printing"]', timeout=30_000)
        page.wait_for_selector("#head-readout[data-drawn='true']", timeout=60_000)
        first_layer = text.splitlines().index(";LAYER:0") + 1    # past the start section (homing, prime)
        for _ in range(120):
            if int(page.get_attribute("#head-readout", "data-line") or 0) > first_layer:
                break
            page.wait_for_timeout(500)
        readout = page.inner_text("#head-readout")
        assert re.search(r"Head of head-bench: X \d+\.\d{3}\s+Y \d+\.\d{3}\s+Z \d+\.\d{3} · line \d+ of \d+",
                         readout), readout
        # the head is where the mock machine is: on the program's path (machine coordinates)
        position = np.asarray([float(v) for v in page.get_attribute("#head-readout", "data-position").split(",")])
        assert distance_to_path(position, moves.starts, moves.ends) < 1e-3, position
        view_id = page.get_attribute("#viewer-panel", "data-view")
        scene = api.get("/api/v1/viewer/scene", params={"view_id": view_id}).json()
        assert scene["focus"]["job_id"] == api.get(f"/api/v1/machines/{machine['id']}").json()["program"]["job_id"]
        assert scene["nodes"]["/focus/head"]["group"] == "head"
        assert any(n.get("role") == "preview" for n in scene["nodes"].values())
        # and the browser draws it: the magenta head among the path's colours
        def magenta(img: np.ndarray) -> int:
            rgb = img.astype(int)
            return int(((rgb[..., 0] > 150) & (rgb[..., 2] > 150) & (rgb[..., 1] < 110)).sum())

        seen = 0  # judged on the frame captured (the head is redrawn once a poll: a later frame may be between)
        for _ in range(120):
            seen = magenta(view_image(page))
            if seen >= 5:
                break
            page.wait_for_timeout(1000)
        assert seen >= 5, "the head is not on the canvas"
        page.set_viewport_size({"width": 1400, "height": 1500})     # the view, the legend and the layers
        save_view_panel(page, screenshot_path("machine-head"))
        # the whole page at the bench: homed, line, elapsed and time left, the console, the head on the path
        card = f'.machine-card[data-id="{machine["id"]}"]'
        page.wait_for_selector(f'{card} .badge.homed[data-homed="true"]')
        page.wait_for_selector(f'{card} .program:has-text("left about")', timeout=30_000)
        page.click(f"{card} details.manual summary")
        # the program's moves (the console keeps the last 4000 lines: the homing's G28 has left
        # it by now when the print ran long, as on a loaded host)
        page.wait_for_selector(f'{card} .console-log:has-text("G1 ")')
        page.screenshot(path=str(screenshot_path("machine-print-3d")), full_page=True)
        assert page.js_errors == []
    finally:
        api.post(f"/api/v1/machines/{machine['id']}/stop")
