"""The closed-loop wizard end to end in a real browser, on a mock machine that holds an
as-made S1 part (a ±0.15 mm machining error, placed 0.03 mm high): plan, probe, review,
print, report — asserting what the operator sees against what the jobs and the mock know."""

from __future__ import annotations

import numpy as np
import pytest

from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.e2e.browser.conftest import screenshot

TRACES = (0, 3)  # a line and an R40 arc


@pytest.fixture(scope="module")
def loop_setup(served) -> dict:
    api = served.api()
    nominal = s1_mesh(grid_mm=0.5).export(file_type="stl")
    truth = as_made(seed=11, amplitude_mm=0.15).mesh(grid_mm=0.5).export(file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("wizard-s1.stl", nominal)}).json()
    real = api.post("/api/v1/parts", files={"file": ("wizard-s1-as-made.stl", truth)}).json()
    traces = api.post(f"/api/v1/parts/{part['id']}/traces:import",
                      json=[s1_traces()[i].to_api() for i in TRACES]).json()["items"]
    machine = api.post("/api/v1/machines", json={
        "name": "wizard-mock", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "placement": {"dz": 0.03}, "probe_noise_mm": 0.001}}).json()
    return {"part": part, "traces": traces, "machine": machine}


def test_wizard_walks_plan_probe_review_print_report(page, served, loop_setup):
    api = served.api()
    part, traces, machine = loop_setup["part"], loop_setup["traces"], loop_setup["machine"]
    page.set_default_timeout(90_000)   # the 3-D view renders in software beside the page: slow under load
    page.on("dialog", lambda dialog: dialog.accept())          # the operator confirms each motion
    page.goto("/loop.html")
    page.wait_for_selector('body[data-ready="1"]')
    page.select_option("#wz-part", part["id"])
    page.wait_for_selector(f'#wz-traces input[value="{traces[-1]["id"]}"]')
    assert page.locator("#wz-traces input:checked").count() == len(TRACES)
    page.select_option("#wz-machine", machine["id"])
    page.click("#wz-connect")
    page.wait_for_selector('#wz-3[data-done="1"]')
    executed_before = api.get(f"/api/v1/machines/{machine['id']}").json()["mock"]["executed_commands"]

    # plan: touches and predicted error shown, and the machine has not moved
    page.click("#wz-plan")
    page.wait_for_selector('#wz-4[data-done="1"]', timeout=60_000)
    touches = int(page.get_attribute("#wz-plan-summary .figure", "data-touches"))
    plan = api.get("/api/v1/jobs?kind=probe_plan&limit=1&include=result").json()["items"][0]
    assert touches == plan["result"]["count"] == len(plan["result"]["points"]) > 0
    assert "predicted error" in page.inner_text("#wz-plan-summary")
    assert api.get(f"/api/v1/machines/{machine['id']}").json()["mock"]["executed_commands"] == executed_before

    # probe, then review: the rebuilt traces and their compensated programs
    page.click("#wz-probe")
    page.wait_for_selector('#wz-6[data-done="1"]', timeout=120_000)
    run = api.get("/api/v1/jobs?kind=probe_run&limit=1&include=result").json()["items"][0]
    assert run["status"] == "succeeded" and len(run["result"]["points"]) == touches
    assert f"{touches} touches" in page.inner_text("#wz-probe-live")
    rows = page.query_selector_all("#wz-review tbody tr")
    assert [r.get_attribute("data-trace") for r in rows] == [t["id"] for t in traces]
    assert all(r.get_attribute("data-ready") == "1" for r in rows)
    rebuilt = {j["params"]["trace_id"]: j for j in api.get("/api/v1/jobs?kind=reconstruct&limit=10&include=result").json()["items"]}
    for row, trace in zip(rows, traces):
        shown = row.query_selector_all("td")[1].inner_text()
        max_um = rebuilt[trace["id"]]["result"]["deviation"]["max_mm"] * 1000
        assert max_um > 20 and shown.startswith(f"{float(f'{max_um:.4g}'):g}"), (shown, max_um)  # the model was off
    screenshot(page, "wizard-review")
    # the field learned from the touches and checked at the verification points is shown; a check
    # asking for attention holds the print until the operator accepts it explicitly
    check = rebuilt[traces[0]["id"]]["result"]["field_check"]
    assert page.locator("#wz-verify tbody tr").count() == len(check["verification"]) == 5
    assert "Learned from" in page.inner_text("#wz-learned")
    if check["needs_attention"]:
        assert page.is_disabled("#wz-print")
        page.check("#wz-accept")

    # print: every compensated trace streamed to the mock, exactly its program
    page.click("#wz-print")
    page.wait_for_selector('#wz-7[data-done="1"]', timeout=120_000)
    items = page.query_selector_all("#wz-prints li")
    assert [i.get_attribute("data-status") for i in items] == ["succeeded"] * len(TRACES)
    prints = api.get(f"/api/v1/jobs?kind=print&machine_id={machine['id']}&limit=10").json()["items"]
    assert len(prints) == len(TRACES) and all(p["result"]["executed"] == p["result"]["total"] for p in prints)

    # report: one page naming every trace and the hash of every compensated program
    report = api.get(f"/api/v1/jobs/{run['id']}/report").text
    for job in api.get("/api/v1/jobs?kind=compensate&limit=10&include=result").json()["items"][:len(TRACES)]:
        program = next(a for a in job["artifacts"] if a["name"] == "print.gcode")
        assert program["meta"]["commands_sha256"] in report
    for trace in traces:
        assert trace["name"] in report
    with page.expect_download() as info:
        page.click("#wz-report-open")
    assert info.value.suggested_filename == f"run-report-{run['id']}.html"
    assert page.js_errors == []


def test_wizard_probes_the_pads_of_an_imported_circuit_by_itself(page, served):
    """Traces from an imported circuit with pads: the loop page adds the import's pad probe rings
    to the plan by itself (the API's closed loop needs them given), probes the pads, and neither
    lists nor prints the rings as traces."""
    import json

    import shapely
    from shapely.geometry import Polygon

    from tests.api.test_circuits import GERBER_MM

    api = served.api()
    nominal = s1_mesh(grid_mm=1.0).export(file_type="stl")
    truth = as_made(seed=13, amplitude_mm=0.1).mesh(grid_mm=1.0).export(file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("wizard-circuit.stl", nominal)}).json()
    real = api.post("/api/v1/parts", files={"file": ("wizard-circuit-as-made.stl", truth)}).json()
    imported = api.post(f"/api/v1/parts/{part['id']}/circuits:import", files=[("files", ("top.gbr", GERBER_MM.encode()))],
                        data={"options": json.dumps({"origin_mm": [5, 10], "standoff_mm": 0.08})})
    assert imported.status_code == 201, imported.text
    body = imported.json()
    traces = [t["trace"]["id"] for t in body["traces"]]
    [ring] = body["probe_trace_ids"]
    machine = api.post("/api/v1/machines", json={
        "name": "wizard-circuit-mock", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "probe_noise_mm": 0.001}}).json()
    page.set_default_timeout(90_000)
    page.on("dialog", lambda dialog: dialog.accept())
    page.goto("/loop.html")
    page.wait_for_selector('body[data-ready="1"]')
    page.select_option("#wz-part", part["id"])
    page.wait_for_selector(f'#wz-traces input[value="{traces[-1]}"]')
    listed = page.eval_on_selector_all("#wz-traces input", "boxes => boxes.map(b => b.value)")
    assert sorted(listed) == sorted(traces)                          # the ring is not offered for printing
    assert page.get_attribute("#wz-pad-rings", "data-rings") == "1"
    assert "pad probe ring" in page.inner_text("#wz-pad-rings")
    page.select_option("#wz-machine", machine["id"])
    page.click("#wz-connect")
    page.wait_for_selector('#wz-3[data-done="1"]')

    page.click("#wz-plan")
    page.wait_for_selector('#wz-4[data-done="1"]', timeout=60_000)
    plan = api.get("/api/v1/jobs?kind=probe_plan&limit=1&include=result").json()["items"][0]
    assert sorted(plan["params"]["trace_ids"]) == sorted(traces + [ring])   # added by the page itself
    assert page.get_attribute("#wz-plan-rings", "data-rings") == "1"

    page.click("#wz-probe")
    page.wait_for_selector('#wz-6[data-done="1"]', timeout=180_000)
    run = api.get("/api/v1/jobs?kind=probe_run&limit=1&include=result").json()["items"][0]
    stations = shapely.points(np.array([p["nominal"][:2] for p in run["result"]["points"]]))
    on_pad = shapely.contains(Polygon(body["pads"][0]["outline_xy_mm"]), stations)
    assert on_pad.sum() >= 1, f"no station on the pad ({len(on_pad)} stations)"   # the pad was probed
    rows = page.eval_on_selector_all("#wz-review tbody tr", "rows => rows.map(r => r.dataset.trace)")
    assert sorted(rows) == sorted(traces)                             # reviewed (and printable): the traces only
    assert page.js_errors == []
