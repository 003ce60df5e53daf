"""The operator's console in a real browser: a STOP on every page that stops a printing
machine, the dashboard home, the job history's filters and paging, results with units."""

from __future__ import annotations

import io
import re
import time

import pytest
import trimesh

try:
    from playwright.sync_api import expect
except ImportError:  # the tests fail or skip in conftest; the module must still import
    expect = None  # type: ignore[assignment]

from tests.e2e.browser.conftest import screenshot
from tests.e2e.browser.test_operator_flow import wait_job

PAGES = ["index.html", "parts.html", "traces.html", "jobs.html", "machines.html"]
SLOW_PROGRAM = "G21\nG90\nG1 X1 Y0 Z5 F600\n" + "".join(f"G1 X{10 + i} Y{i % 7} F30\n" for i in range(60))


@pytest.fixture(scope="module")
def sliced(served) -> dict:
    """A 20 x 20 x 5 mm box, sliced and filled: a toolpath job with a print time."""
    api = served.api()
    buffer = io.BytesIO()
    mesh = trimesh.creation.box(extents=(20, 20, 5))
    mesh.apply_translation([10, 10, 2.5])
    mesh.export(buffer, file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("console-box.stl", buffer.getvalue())}).json()
    sliced = wait_job(api,
                      api.post("/api/v1/jobs", json={"kind": "slice", "params": {"part_id": part["id"]}}).json()["id"],
                      90)
    assert sliced["status"] == "succeeded", sliced
    toolpath = wait_job(api, api.post("/api/v1/jobs", json={"kind": "toolpath", "params": {
        "slice_job_id": sliced["id"], "pattern": "lines"}}).json()["id"], 90)
    assert toolpath["status"] == "succeeded", toolpath
    return {"part": part, "slice": sliced, "toolpath": toolpath}


@pytest.mark.parametrize("name", PAGES)
def test_stop_is_on_every_page_in_view(page, name):
    page.goto(f"/{name}")
    stop = page.wait_for_selector("#stop-all")
    box = stop.bounding_box()
    assert box is not None and box["y"] + box["height"] <= 900 and box["width"] > 40
    page.mouse.wheel(0, 3000)                      # still there after scrolling (sticky header)
    assert page.is_visible("#stop-all")
    assert stop.evaluate("(b) => getComputedStyle(b).backgroundColor") == "rgb(207, 34, 46)"


def test_global_stop_stops_a_printing_machine_from_the_home_page(page, served):
    api = served.api()
    machine = api.post("/api/v1/machines", json={"name": "console-mock", "port": "mock://",
                                                 "mock": {"time_scale": 1.0}}).json()
    assert api.post(f"/api/v1/machines/{machine['id']}/connect").status_code == 200
    program = api.post("/api/v1/programs", files={"file": ("slow.gcode", SLOW_PROGRAM.encode())}).json()
    assert api.post(f"/api/v1/machines/{machine['id']}/print", json={"program_id": program["id"]}).status_code == 202
    page.goto("/index.html")
    row = f'#dash-machines .machine[data-id="{machine["id"]}"]'
    page.wait_for_selector(f'{row} [data-state="printing"]', timeout=20_000)
    assert "lines" in page.inner_text(row)
    page.click("#stop-all")
    page.wait_for_selector(f'{row} [data-state="error"]', timeout=10_000)
    executed = api.get(f"/api/v1/machines/{machine['id']}").json()["mock"]["executed_commands"]
    time.sleep(1.0)
    assert api.get(f"/api/v1/machines/{machine['id']}").json()["mock"]["executed_commands"] == executed
    assert executed < len(SLOW_PROGRAM.splitlines())
    screenshot(page, "dashboard")


def test_dashboard_shows_recent_results_with_units(page, sliced):
    page.goto("/index.html")
    line = page.wait_for_selector(f'#dash-recent [data-id="{sliced["toolpath"]["id"]}"]')
    text = line.inner_text()
    assert "toolpath" in text and re.search(r"\d (mm|µm|s|min)", text), text
    assert page.js_errors == []


def test_result_figures_have_units_and_no_float_noise(page, sliced):
    job = sliced["toolpath"]
    page.goto(f"/jobs.html?job={job['id']}")
    table = page.wait_for_selector("#result-figures")
    time_row = page.inner_text('#result-figures tr[data-key="time_s"] td')
    seconds = job["result"]["time_s"]
    minutes = int(seconds // 60)
    assert (f"{minutes} min" in time_row) if seconds >= 60 else time_row.endswith(" s"), (time_row, seconds)
    assert not re.search(r"\d\.\d{6,}", table.inner_text())       # no 17-digit numbers
    assert not page.is_visible("#job-result")                      # raw JSON one click away
    page.click("text=Raw result (JSON)")
    assert page.is_visible("#job-result")


def test_history_filters_by_kind_and_part_and_pages(page, served, sliced):
    api = served.api()
    page.goto("/jobs.html")
    page.wait_for_selector("#jobs-body tr")
    page.wait_for_selector('body[data-ready="1"]')
    page.select_option("#filter-kind", "toolpath")
    page.wait_for_selector("#jobs-body tr[data-id]")                    # selectors: the pages' CSP forbids eval
    expect(page.locator("#jobs-body tr[data-id] strong").filter(has_not_text="toolpath")).to_have_count(0)
    page.select_option("#filter-kind", "")
    page.select_option("#filter-part", sliced["part"]["id"])
    expected = api.get(f"/api/v1/jobs?part_id={sliced['part']['id']}&top_level=true").json()["total"]
    expect(page.locator("#page-info")).to_have_text(re.compile(f"of {expected}$"))   # selectors: CSP forbids eval
    # the part's history shows its slice job (waited for: the rows are drawn after the count)
    expect(page.locator(f'#jobs-body tr[data-id="{sliced["slice"]["id"]}"]')).to_have_count(1)
    part_of = {row.get_attribute("data-id") for row in page.query_selector_all("#jobs-body tr[data-id]")}
    listed = {j["id"] for j in api.get(f"/api/v1/jobs?part_id={sliced['part']['id']}&top_level=true&limit=200")
              .json()["items"]}
    assert part_of <= listed, part_of - listed                             # only the part's jobs
    screenshot(page, "history")
    assert page.js_errors == []


def test_a_late_answer_to_an_older_filter_does_not_replace_the_newer_one(page, served, sliced):
    """The history's answers may arrive out of order: the unfiltered query is held back until
    the part filter's answer is shown, then let through; the page keeps the part filter's jobs."""
    api = served.api()
    expected = api.get(f"/api/v1/jobs?part_id={sliced['part']['id']}&top_level=true").json()["total"]
    everything = api.get("/api/v1/jobs?top_level=true").json()["total"]
    assert everything > expected
    page.goto("/jobs.html")
    page.wait_for_selector('body[data-ready="1"]')
    held = []

    def hold_unfiltered(route):
        if "part_id" in route.request.url:
            route.continue_()
        else:
            held.append(route)

    page.route(re.compile(r".*/api/v1/jobs\?.*"), hold_unfiltered)
    page.select_option("#filter-status", "succeeded")
    page.select_option("#filter-status", "")            # an unfiltered query: held
    page.select_option("#filter-part", sliced["part"]["id"])
    expect(page.locator("#page-info")).to_have_text(re.compile(f"of {expected}$"))
    assert held, "the unfiltered query was not sent"
    with page.expect_response(lambda r: "/api/v1/jobs?" in r.url and "part_id" not in r.url):
        for route in held:
            route.continue_()
    page.wait_for_timeout(300)                           # time to (wrongly) render the late answer
    expect(page.locator("#page-info")).to_have_text(re.compile(f"of {expected}$"))
    page.unroute(re.compile(r".*/api/v1/jobs\?.*"))
    assert page.js_errors == []


def test_first_run_without_a_key_shows_no_error_and_a_wrong_key_is_not_saved(browser, served):
    context = browser.new_context(viewport={"width": 1440, "height": 900}, base_url=served.base)
    page = context.new_page()
    page.set_default_timeout(30_000)
    try:
        for name in PAGES:
            page.goto(f"/{name}")
            page.wait_for_selector("#messages .msg.info")
            page.wait_for_timeout(300)
            assert page.query_selector_all("#messages .msg.error") == [], name   # no 401 before any key
        page.fill("#api-key", "cf_not_a_key")
        page.click("#key-form button")
        page.wait_for_selector("#messages .msg.error >> text=API key not saved")
        assert page.evaluate("localStorage.getItem('conforma.apiKey')") is None
        page.fill("#api-key", served.key)
        page.click("#key-form button")
        page.wait_for_selector("#messages .msg.info >> text=checked and saved")
        assert page.evaluate("localStorage.getItem('conforma.apiKey')") == served.key
        assert page.query_selector_all("#messages .msg.error") == []            # the refusal went away
        page.goto("/jobs.html")
        page.wait_for_selector("#jobs-body tr")                                  # pages load their data now
        assert page.query_selector_all("#messages .msg.error") == []
    finally:
        context.close()


def test_slice_and_toolpath_results_draw_their_layer_curves(page, sliced):
    for job, series in ((sliced["slice"], "thickness"), (sliced["toolpath"], "time_s")):
        page.goto(f"/jobs.html?job={job['id']}")
        figure = page.wait_for_selector("figure.chart")
        assert figure.get_attribute("data-series") == series
        assert int(figure.get_attribute("data-rows")) == len(job["result"]["layers"]) > 1
        points = page.get_attribute("figure.chart polyline", "points").split()
        assert len(points) == len(job["result"]["layers"])
    assert page.js_errors == []


def test_machines_page_jogs_homes_and_talks_to_the_firmware(page, served):
    api = served.api()
    machine = api.post("/api/v1/machines", json={"name": "manual-mock", "port": "mock://"}).json()
    spare = api.post("/api/v1/machines", json={"name": "spare-mock", "port": "mock://"}).json()
    assert api.post(f"/api/v1/machines/{machine['id']}/connect").status_code == 200
    page.on("dialog", lambda dialog: dialog.accept())
    page.goto("/machines.html")
    card = f'.machine-card[data-id="{machine["id"]}"]'
    page.wait_for_selector(f"{card} [data-state='idle']")
    page.click(f"{card} details.manual summary")
    page.click(f"{card} .act-home")
    page.select_option(f"{card} .jog-step", "10")
    page.click(f"{card} .jog-xp")
    page.click(f"{card} .jog-zp")
    expect(page.locator(f"{card} .pos")).to_contain_text("Z 10.000")
    assert api.get(f"/api/v1/machines/{machine['id']}").json()["position"][:3] == pytest.approx([10, 0, 10], abs=1e-3)
    page.fill(f"{card} .console-line", "M114")
    page.click(f"{card} form.console button")
    expect(page.locator(f"{card} pre.console-log")).to_contain_text("X:10")
    page.click(f'.machine-card[data-id="{spare["id"]}"] details.manual summary')
    page.click(f'.machine-card[data-id="{spare["id"]}"] .act-delete')
    expect(page.locator(f'.machine-card[data-id="{spare["id"]}"]')).to_have_count(0)
    assert api.get(f"/api/v1/machines/{spare['id']}").status_code == 404
    screenshot(page, "machines-manual")
    assert page.js_errors == []
