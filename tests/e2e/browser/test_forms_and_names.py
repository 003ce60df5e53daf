"""Forms by task and names instead of ids, read from what the page shows: a kind's form
shows its mode's fields with human labels and units, folds the advanced ones, starts a
toolpath from a paste (no 210 °C nozzle) and a material picker fills it; the trace form
shows line or arc fields, never both; the machine page shows and edits the machine's
dispense profile; traces are listed by name and net, jobs and programs by part · trace ·
kind, with ids only on hover; the dashboard counts in words."""

from __future__ import annotations

import io
import json

import pytest
import trimesh

from app.reference.s1 import s1_mesh
from tests.circuits.boards import USB_PADS_BOARD
from tests.e2e.browser.conftest import screenshot
from tests.e2e.browser.test_operator_flow import wait_job


@pytest.fixture(scope="module")
def sliced_box(served) -> dict:
    """A 30 x 30 x 4 mm box and a succeeded uniform slice of it."""
    api = served.api()
    buffer = io.BytesIO()
    mesh = trimesh.creation.box(extents=(30, 30, 4))
    mesh.apply_translation([15, 15, 2])
    mesh.export(buffer, file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("forms-box.stl", buffer.getvalue())}).json()
    job = wait_job(api, api.post("/api/v1/jobs", json={"kind": "slice", "params": {
        "part_id": part["id"], "layer_mm": 1.0}}).json()["id"], 90)
    assert job["status"] == "succeeded", job
    return {"part": part, "slice": job}


@pytest.fixture(scope="module")
def dome(served) -> dict:
    """The dome part ("dome") with a KiCad board imported: one GND trace and three pad rings."""
    api = served.api()
    stl = s1_mesh(grid_mm=1.0).export(file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("dome.stl", stl)}, data={"name": "dome"}).json()
    done = api.post(f"/api/v1/parts/{part['id']}/circuits:import",
                    files=[("files", ("usb.kicad_pcb", USB_PADS_BOARD.encode()))],
                    data={"options": json.dumps({"origin_mm": [20.0, 20.0]})})
    assert done.status_code == 201, done.text
    (trace,) = [t["trace"] for t in done.json()["traces"]]
    return {"part": part, "trace": api.get(f"/api/v1/traces/{trace['id']}").json(), "import": done.json()}


def _label(page, name: str) -> str:
    return page.inner_text(f'label[for="param-{name}"]')


def test_the_toolpath_form_starts_from_a_paste_and_a_preset_fills_it(page, served, sliced_box):
    page.goto(f"/jobs.html?kind=toolpath&slice_job_id={sliced_box['slice']['id']}")
    page.wait_for_selector('#job-form-body[data-kind="toolpath"]')
    assert _label(page, "line_width_mm") == "Line width (mm)"
    assert _label(page, "print_feed_mm_min") == "Print feed (mm/min)"
    assert _label(page, "nozzle_temp_c") == "Nozzle temperature (°C)"
    # a product for printing electronics: the form starts from silver paste, dispensing, no heaters
    assert page.input_value("#material-preset") == "silver_paste"
    assert page.input_value("#param-mode") == '"dispense"'
    assert page.input_value("#param-line_width_mm") == "0.25"
    assert not page.is_visible("#param-nozzle_temp_c") and not page.is_visible("#param-bed_temp_c")
    # advanced fields are folded, and a mode's own advanced fields only in that mode
    assert page.is_visible("#advanced-params") and not page.is_visible("#param-accel_mm_s2")
    page.click("#advanced-params summary")
    assert page.is_visible("#param-accel_mm_s2") and page.is_visible("#param-dispense_on")
    assert not page.is_visible("#param-retract_mm")
    screenshot(page, "form-toolpath-paste")
    with page.expect_request(lambda r: r.url.endswith("/api/v1/jobs") and r.method == "POST") as sent:
        page.click("#submit-job")
    params = sent.value.post_data_json["params"]
    assert params["mode"] == "dispense" and params["line_width_mm"] == 0.25
    assert "nozzle_temp_c" not in params and "retract_mm" not in params      # hidden fields are not sent
    page.wait_for_selector("#job-detail[data-job-id]")
    job = served.api().get(f"/api/v1/jobs/{page.get_attribute('#job-detail', 'data-job-id')}").json()
    assert job["kind"] == "toolpath" and job["params"]["mode"] == "dispense"
    # a printed substrate's plastic: the picker fills the temperatures, which now show
    page.select_option("#material-preset", "petg")
    assert page.input_value("#param-mode") == '"extrude"'
    assert page.is_visible("#param-nozzle_temp_c") and page.input_value("#param-nozzle_temp_c") == "240"
    assert page.input_value("#param-bed_temp_c") == "80" and page.is_visible("#param-retract_mm")
    assert not page.is_visible("#param-dispense_on")
    assert page.js_errors == []


def test_the_slice_form_shows_the_chosen_modes_fields_only(page):
    page.goto("/jobs.html?kind=slice")
    page.wait_for_selector('#job-form-body[data-kind="slice"]')
    assert _label(page, "layer_mm") == "Layer thickness (mm)"
    assert page.is_visible("#param-layer_mm") and not page.is_visible("#param-cusp_mm")
    assert not page.is_visible("#param-l_min") and not page.is_visible("#param-sigma0")
    page.select_option("#param-mode", '"cusp"')
    assert page.is_visible("#param-cusp_mm") and _label(page, "cusp_mm") == "Allowed cusp height (mm)"
    assert page.is_visible("#param-l_min") and _label(page, "l_min") == "Thinnest layer (mm)"
    assert not page.is_visible("#param-layer_mm") and not page.is_visible("#param-sigma0")
    page.select_option("#param-mode", '"cavity"')
    assert page.is_visible("#param-sigma0") and not page.is_visible("#param-cusp_mm")
    screenshot(page, "form-slice-cavity")
    assert page.js_errors == []


def test_one_trace_or_several_are_alternatives_in_the_probe_plan_form(page, dome):
    page.goto(f"/jobs.html?kind=probe_plan&trace_id={dome['trace']['id']}")
    page.wait_for_selector('#job-form-body[data-kind="probe_plan"]')
    assert page.is_visible("#param-trace_id") and not page.is_visible("#param-trace_ids")
    assert page.input_value("#choice-traces") == "trace_id"
    page.select_option("#choice-traces", "trace_ids")
    assert page.is_visible("#param-trace_ids") and not page.is_visible("#param-trace_id")
    # the trace suggestion names the trace, its net and its part, not an id
    options = page.eval_on_selector_all("#param-trace_id-list option", "os => os.map(o => o.textContent)")
    assert f"{dome['trace']['name']} · GND on dome" in options


def test_the_trace_form_shows_line_or_arc_fields_never_both(page, sliced_box):
    page.goto(f"/traces.html?part={sliced_box['part']['id']}")
    page.wait_for_selector("#trace-form")
    assert page.is_visible("#x0") and not page.is_visible("#radius")
    page.select_option("#type", "arc")
    assert page.is_visible("#radius") and page.is_visible("#cx") and not page.is_visible("#x0")
    page.select_option("#type", "nurbs")
    assert page.is_visible("#points") and page.is_visible("#degree") and not page.is_visible("#radius")


def test_traces_are_listed_by_name_and_net_with_ids_on_hover(page, dome):
    page.goto(f"/traces.html?part={dome['part']['id']}")
    row = page.wait_for_selector(f'#traces-body tr[data-id="{dome["trace"]["id"]}"]')
    assert row.inner_text().split("\t")[:2] == [dome["trace"]["name"], "GND"]
    assert dome["trace"]["id"] not in page.inner_text("#traces-table")       # ids only on hover
    assert row.eval_on_selector("td", "td => td.title") == dome["trace"]["id"]
    rings = page.locator('#traces-body td.net:has-text("pad probe ring")').count()
    names = page.locator("#traces-body tr strong").all_inner_texts()
    assert rings == 3 and len(set(names)) == len(names)                        # no two rings share a name
    assert page.inner_text("#trace-part option:checked") == "dome"


def test_the_traces_page_never_opens_on_a_mocks_as_made_part(page, served):
    api = served.api()
    buffer = io.BytesIO()
    trimesh.creation.box(extents=(10, 10, 2)).export(buffer, file_type="stl")
    truth = api.post("/api/v1/parts", files={"file": ("truth.stl", buffer.getvalue())}, data={"name": "as made"}).json()
    api.post("/api/v1/machines", json={"name": "truth bench", "port": "mock://", "mock": {"true_part_id": truth["id"]}})
    page.goto("/traces.html")                                                  # the newest part is the as-made one
    page.wait_for_selector("#trace-part option", state="attached")
    assert page.input_value("#trace-part") != truth["id"]
    assert page.inner_text(f'#trace-part option[value="{truth["id"]}"]') == "as made — a mock's as-made part"


def test_jobs_programs_and_the_dashboard_use_names(page, served, dome):
    api = served.api()
    plan = wait_job(api, api.post("/api/v1/jobs", json={"kind": "probe_plan", "params": {
        "trace_id": dome["trace"]["id"], "method": "uniform", "count": 6}}).json()["id"], 90)
    assert plan["status"] == "succeeded", plan
    title = f"dome · {dome['trace']['name']} (GND) · probe plan"
    page.goto("/jobs.html")
    row = page.wait_for_selector(f'#jobs-body tr[data-id="{plan["id"]}"]')
    assert row.inner_text().splitlines()[0] == title
    assert plan["id"] not in page.inner_text("#jobs-table")
    page.goto("/index.html")
    line = page.wait_for_selector(f'#dash-recent [data-id="{plan["id"]}"]')
    text = line.inner_text()
    assert title in text and "6 points" in text and "items" not in text, text
    screenshot(page, "dashboard-names")
    assert page.js_errors == []


def test_the_machine_page_shows_and_edits_the_dispense_profile(page, served):
    api = served.api()
    machine = api.post("/api/v1/machines", json={"name": "paste bench", "port": "mock://"}).json()
    assert api.patch(f"/api/v1/machines/{machine['id']}", json={"material": "silver_paste"}).status_code == 200
    page.goto("/machines.html")
    card = f'.machine-card[data-id="{machine["id"]}"]'
    page.wait_for_selector(f'{card} .dispense-summary:has-text("Silver paste")')
    assert "250 kPa · on 120 ms / off 80 ms" in page.inner_text(f"{card} .dispense-summary")
    page.click(f"{card} details.dispense summary")
    page.wait_for_selector(f"{card} .dispense-form")
    assert page.inner_text(f'{card} label[for="param-pressure_kpa"]') == "Pressure (kPa)"
    assert page.input_value(f"{card} #param-on_delay_ms") == "120"
    page.select_option(f"{card} .dispense-preset", "dielectric_ink")
    assert page.input_value(f"{card} #param-standoff_mm") == "0.15"
    page.fill(f"{card} #param-off_delay_ms", "95")            # the machine's own profile of the ink
    page.click(f"{card} .dispense-save")
    page.wait_for_selector(f'{card} .dispense-summary:has-text("off 95 ms")')
    assert page.inner_text(f"{card} .dispense-summary").startswith("Dielectric ink")
    profile = api.get(f"/api/v1/machines/{machine['id']}").json()["profile"]
    tuned = {"material": "dielectric_ink", "pressure_kpa": 150.0, "on_delay_ms": 80.0, "off_delay_ms": 95.0,
             "standoff_mm": 0.15, "feed_mm_min": 400.0}
    assert profile["dispense"] == tuned and profile["dispense_by_material"]["dielectric_ink"] == tuned
    screenshot(page, "machine-dispense")
    assert page.js_errors == []
