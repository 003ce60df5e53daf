"""Result views in a real browser: the probe plan's stations on the part, compensation's
standoff along the trace and its program time, a five-axis program's A/C angles and tip
speed, and the machines page's program list whose Print asks first (machine, program,
lines, estimated time), shows progress and keeps the STOP beside it.  Every figure on
screen is checked against what the API and the mock know."""

from __future__ import annotations

import re

import numpy as np
import pytest
from PIL import Image

from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.e2e.browser.conftest import screenshot, screenshot_path
from tests.e2e.browser.pixels import save_view_panel, wait_for_view
from tests.e2e.browser.test_operator_flow import wait_job

TRACES = (0, 6)  # a line and a NURBS


def duration(seconds: float) -> str:
    """The pages' duration format (web/js/results.js)."""
    s = float(seconds)
    if s < 1:
        return f"{float(f'{s * 1000:.3g}'):g} ms"
    if s < 60:
        return f"{float(f'{s:.3g}'):g} s"
    if s < 3600:
        return f"{int(s // 60)} min {round(s % 60):02d} s"
    minutes = round(s / 60)
    return f"{minutes // 60} h {minutes % 60:02d} min"


def run(api, kind: str, params: dict, timeout: float = 120) -> dict:
    response = api.post("/api/v1/jobs", json={"kind": kind, "params": params})
    assert response.status_code == 202, response.text
    job = wait_job(api, response.json()["id"], timeout=timeout)
    assert job["status"] == "succeeded", job.get("error")
    return job


@pytest.fixture(scope="module")
def jobs(served) -> dict:
    api = served.api()
    part = api.post("/api/v1/parts",
                    files={"file": ("views-s1.stl", s1_mesh(grid_mm=0.5).export(file_type="stl"))}).json()
    traces = api.post(f"/api/v1/parts/{part['id']}/traces:import",
                      json=[s1_traces()[i].to_api() for i in TRACES]).json()["items"]
    truth = as_made(seed=5, amplitude_mm=0.15)
    plan = run(api, "probe_plan", {"trace_ids": [t["id"] for t in traces]})
    one = run(api, "probe_plan", {"trace_id": traces[0]["id"], "method": "uniform", "count": 14})
    xy = np.asarray(one["result"]["points"])[:, :2]
    measured = np.column_stack([xy, truth.true_height(xy)])
    rebuilt = run(api, "reconstruct", {"trace_id": traces[0]["id"], "points": measured.tolist(), "method": "deviation"})
    compensated = run(api, "compensate",
                      {"trace_id": traces[0]["id"], "reconstruct_job_id": rebuilt["id"], "hold_mm": 1.0})
    five = run(api, "five_axis", {"part_id": part["id"], "trace_id": traces[1]["id"], "pivot": [0.0, 0.0, -10.0]})
    return {"part": part, "traces": traces, "plan": plan, "rebuilt": rebuilt, "compensate": compensated, "five": five}


def test_probe_plan_view_draws_the_stations_on_the_part(page, jobs):
    plan = jobs["plan"]
    page.goto(f"/jobs.html?job={plan['id']}")
    figure = page.wait_for_selector("#plan-view figure.top-view")
    assert int(figure.get_attribute("data-stations")) == plan["result"]["count"] == len(plan["result"]["points"])
    assert page.locator("#plan-view circle.station").count() == plan["result"]["count"]
    assert page.locator("#plan-view polyline.trace").count() == len(TRACES)
    assert page.locator("#plan-view rect.part-outline").count() == 1
    sd_um = plan["result"]["field"]["max_sd_mm"] * 1000
    shown = page.inner_text('#plan-view tr[data-key="predicted_sd_mm"] td')
    assert shown.endswith("µm") and float(shown.split()[0]) == pytest.approx(sd_um, rel=1e-3)
    # every station lies inside the part outline on screen
    inside = page.evaluate("""() => {
        const r = document.querySelector('#plan-view rect.part-outline').getBBox();
        return [...document.querySelectorAll('#plan-view circle.station')].every((c) => {
            const x = +c.getAttribute('cx'), y = +c.getAttribute('cy');
            return x >= r.x - 0.5 && x <= r.x + r.width + 0.5 && y >= r.y - 0.5 && y <= r.y + r.height + 0.5; }); }""")
    assert inside
    assert page.locator("#job-result").count() == 1  # raw JSON one click away
    page.locator("#plan-view").scroll_into_view_if_needed()
    screenshot(page, "result-probe-plan")
    assert page.js_errors == []


def test_compensation_view_compares_nominal_and_compensated_standoff(page, served, jobs):
    job, rebuilt = jobs["compensate"], jobs["rebuilt"]
    summary = served.api().get(f"/api/v1/jobs/{job['id']}/artifacts/print.gcode/summary").json()
    page.goto(f"/jobs.html?job={job['id']}")
    figure = page.wait_for_selector("#standoff-plot")
    samples = rebuilt["result"]["deviation"]["samples"]
    assert int(figure.get_attribute("data-rows")) == len(samples)
    assert figure.get_attribute("data-series") == "nominal_program_um,compensated_um"
    # the nominal program's curve is the set standoff minus the rebuilt deviation, in µm
    points = page.eval_on_selector("#standoff-plot polyline", "p => p.getAttribute('points')").split()
    ys = np.array([float(p.split(",")[1]) for p in points])
    dz = np.array([d for _s, d in samples])
    assert np.corrcoef(ys, dz)[0, 1] > 0.999  # screen y grows downwards: standoff - dz falls as dz rises
    # the posterior band only where the reconstruction has a bound (the field method's)
    assert (page.locator("#standoff-plot polygon.band").count() == 1) == (rebuilt["result"].get("bound_mm") is not None)
    assert page.inner_text('#compensate-view tr[data-key="time_s"] td') == duration(summary["time_s"])
    assert page.inner_text('#compensate-view tr[data-key="lines"] td') == str(summary["lines"])
    assert page.inner_text('#compensate-view tr[data-key="segments"] td').startswith(str(job["result"]["segments"]))
    chord = page.inner_text('#compensate-view tr[data-key="max_chord_error_mm"] td')
    assert chord.startswith("≤") and chord.endswith("µm")
    assert float(chord.split()[1]) == pytest.approx(job["result"]["max_chord_error_mm"] * 1000, rel=1e-3)
    worst = page.inner_text('#compensate-view tr[data-key="nominal_error_mm"] td')
    assert float(worst.split()[0]) == pytest.approx(max(abs(d) for d in dz) * 1000, rel=1e-3)
    page.locator("#compensate-view").scroll_into_view_if_needed()
    screenshot(page, "result-compensate")
    assert page.js_errors == []


def test_five_axis_view_plots_angles_and_tip_speed(page, served, jobs):
    job = jobs["five"]
    summary = served.api().get(f"/api/v1/jobs/{job['id']}/artifacts/five_axis.gcode/summary").json()
    rotary = summary["rotary"]
    assert rotary is not None and np.ptp(rotary["a_deg"]) > 0.1
    # the planned feed is the tip speed along the workpiece (the planner's own claim)
    feed = job["result"]["feed_mm_min"] / 60
    speeds = np.array(rotary["tip_speed_mm_s"])
    assert np.median(speeds) == pytest.approx(feed, rel=0.02)
    page.goto(f"/jobs.html?job={job['id']}")
    angles = page.wait_for_selector("#angles-plot")
    speed = page.wait_for_selector("#tip-speed-plot")
    assert int(angles.get_attribute("data-rows")) == len(rotary["s_mm"]) > 10
    assert angles.get_attribute("data-series") == "a_deg,c_deg"
    assert speed.get_attribute("data-series") == "tip_speed_mm_s"
    assert page.inner_text('#five-axis-view tr[data-key="time_s"] td') == duration(summary["time_s"])
    page.locator("#five-axis-view").scroll_into_view_if_needed()
    screenshot(page, "result-five-axis")
    assert page.js_errors == []


def test_machines_page_prints_a_listed_program_after_a_confirmation(page, served, jobs):
    api = served.api()
    job = jobs["compensate"]
    # every modelled duration x 5: the print outlasts the page's checks on a loaded box (at
    # real time it ended between the progress bar showing and its text being read); the
    # e-stop at the end stops it
    machine = api.post("/api/v1/machines", json={"name": "print-list-mock", "port": "mock://", "dialect": "marlin",
                                                 "mock": {"time_scale": 5.0}}).json()
    assert api.post(f"/api/v1/machines/{machine['id']}/connect").status_code == 200
    summary = api.get(f"/api/v1/jobs/{job['id']}/artifacts/print.gcode/summary").json()
    page.goto("/machines.html")
    sel = f'.machine-card[data-id="{machine["id"]}"]'
    row = page.wait_for_selector(f'{sel} tr[data-job="{job["id"]}"][data-artifact="print.gcode"]')
    # newest first: the listed programs' jobs are in creation order, newest on top
    listed = page.eval_on_selector_all(f"{sel} .programs-table tbody tr", "rows => rows.map(r => r.dataset.job)")
    created = {j["id"]: j["created_at"] for k in ("compensate", "five_axis") for j in
               api.get(f"/api/v1/jobs?kind={k}&status=succeeded&limit=50").json()["items"]}
    stamps = [created[j] for j in listed if j in created]
    assert stamps == sorted(stamps, reverse=True) and len(stamps) >= 2
    asked: list[str] = []

    def answer(dialog) -> None:  # type: ignore[no-untyped-def]
        asked.append(dialog.message)
        dialog.accept()

    page.once("dialog", answer)
    row.query_selector("button.print-program").click()
    page.wait_for_selector(f'{sel} [data-state="printing"]', timeout=20_000)
    assert len(asked) == 1
    text = asked[0]
    assert "print-list-mock" in text and "print.gcode" in text and "compensated program" in text
    assert job["id"] not in text and "dispense profile: none" in text  # named, not numbered; the machine's profile
    assert f"{summary['lines']} lines" in text and f"estimated time {duration(summary['time_s'])}" in text
    bar = page.wait_for_selector(f"{sel} .print-progress:not([hidden])")
    assert re.search(r"line \d+ of \d+ \(\d+ %\)", page.inner_text(f"{sel} .program"))
    assert 0.0 <= float(bar.get_attribute("value") or bar.evaluate("b => b.value")) <= 1.0
    # the machine's STOP sits right below the progress, on screen without scrolling
    stop = page.locator(f"{sel} .estop").bounding_box()
    assert stop is not None and stop["y"] + stop["height"] <= 900
    screenshot(page, "machines-print")
    prints = api.get(f"/api/v1/jobs?kind=print&machine_id={machine['id']}").json()["items"]
    assert [{k: p["params"][k] for k in ("machine_id", "job_id", "artifact")} for p in prints] == [
        {"machine_id": machine["id"], "job_id": job["id"], "artifact": "print.gcode"}]
    page.click(f"{sel} .estop")
    page.wait_for_selector(f'{sel} [data-state="error"]')
    assert page.js_errors == []


def test_declining_the_confirmation_prints_nothing(page, served, jobs):
    api = served.api()
    machine = api.post("/api/v1/machines", json={"name": "decline-mock", "port": "mock://", "dialect": "marlin"}).json()
    page.goto("/machines.html")
    sel = f'.machine-card[data-id="{machine["id"]}"]'
    row = page.wait_for_selector(f'{sel} tr[data-job="{jobs["compensate"]["id"]}"][data-artifact="print.gcode"]')
    page.once("dialog", lambda dialog: dialog.dismiss())
    row.query_selector("button.print-program").click()
    page.wait_for_timeout(1500)
    assert api.get(f"/api/v1/jobs?kind=print&machine_id={machine['id']}").json()["total"] == 0


@pytest.mark.timeout(900)   # the module's jobs, then software GL drawing beside them on a loaded host
def test_3d_view_of_a_compensation_shows_the_deviation_standoff_errors_and_a_legend(page, served, jobs):
    api = served.api()
    job, rebuilt = jobs["compensate"], jobs["rebuilt"]
    page.goto(f"/jobs.html?job={job['id']}")
    page.click("#open-3d")
    page.wait_for_selector("#viewer-panel[data-generation]", state="attached")
    view_id = page.get_attribute("#viewer-panel", "data-view")
    scene = api.get("/api/v1/viewer/scene", params={"view_id": view_id}).json()
    assert scene["focus"]["job_id"] == job["id"]
    ribbons = [n for n in scene["nodes"].values() if n["group"] == "deviation"]
    assert len(ribbons) == 1 and ribbons[0]["signed"]
    colored = {k: v for k, v in scene["nodes"].items() if v.get("colored_by") == "standoff_error"}
    assert {v["role"] for v in colored.values()} == {"nominal", "compensated"}
    [legend] = scene["legends"]
    worst = max(abs(d) for _s, d in rebuilt["result"]["deviation"]["samples"]) * 1000
    assert legend["unit"] == "µm" and legend["hi"] == pytest.approx(-legend["lo"])
    # the scale's end is the largest value drawn: the deviation read at the trace's points (within 2 %
    # of the rebuilt samples' worst), and never a clipped colour
    assert legend["hi"] == pytest.approx(worst, rel=0.02)
    assert legend["hi"] == pytest.approx(max(abs(legend["data_min"]), legend["data_max"]))
    # and the browser draws it: the slate part framed in the canvas, the nominal program's
    # standoff errors at both saturated ends of the scale (it runs 70-140 µm off, above and
    # below), viser's panel with the colour scale and its unit
    counts, img = wait_for_view(page, lambda c: c.slate > 0.02 * c.total and c.blue_end >= 8 and c.red_end >= 8)
    Image.fromarray(img).save(screenshot_path("view3d-compensate-canvas"))
    assert counts.slate > 0.02 * counts.total, f"the part is not on the canvas: {counts}"
    assert counts.blue_end >= 8 and counts.red_end >= 8, f"no standoff-error colours on the canvas: {counts}"
    frame = page.frame_locator("#viewer-iframe")
    frame.locator(".conforma-legend").first.wait_for(state="attached", timeout=30_000)
    assert "µm" in frame.locator(".conforma-legend").first.inner_text()
    save_view_panel(page, screenshot_path("view3d-compensate"))
    assert page.js_errors == []


def test_reconstruction_view_plots_the_probe_points_in_micrometres_with_nice_ticks(page, jobs):
    job = jobs["rebuilt"]
    samples = job["result"]["deviation"]["samples"]
    page.goto(f"/jobs.html?job={job['id']}")
    figure = page.wait_for_selector("#reconstruct-view figure.chart")
    assert figure.get_attribute("data-unit") == "µm"                       # deviations below 1 mm read in µm
    assert int(figure.get_attribute("data-points")) == len(samples)
    ticks = [float(t) for t in page.locator("#reconstruct-view .tick-y").all_text_contents()]
    assert len(ticks) >= 3 and not any("e" in t for t in page.locator("#reconstruct-view .tick-y").all_text_contents())
    steps = np.diff(ticks)
    assert np.allclose(steps, steps[0])
    mantissa = steps[0] / 10 ** np.floor(np.log10(steps[0]))
    assert min(abs(mantissa - m) for m in (1, 2, 5, 10)) < 1e-6             # a 1-2-5 step
    dz_um = np.array([d for _s, d in samples]) * 1000
    assert ticks[0] <= dz_um.min() and ticks[-1] >= dz_um.max()              # the ticks cover every point
    worst = page.inner_text('#reconstruct-view tr[data-key="deviation"] td').split("/")[0]
    assert float(worst.split()[0]) == pytest.approx(job["result"]["deviation"]["max_mm"] * 1000, rel=1e-3)
    assert (page.locator("#reconstruct-view polygon.band").count() == 1) == (job["result"].get("bound_mm") is not None)
    assert page.js_errors == []


def test_the_dashboard_headlines_give_the_figure_that_matters(page, jobs):
    page.goto("/index.html")
    comp = page.wait_for_selector(f'#dash-recent [data-id="{jobs["compensate"]["id"]}"] .headline')
    text = comp.inner_text()
    assert text.startswith("chord error ≤") and "Dispense" not in text
    chord_um = float(text.split("≤")[1].split()[0])
    assert chord_um == pytest.approx(jobs["compensate"]["result"]["max_chord_error_mm"] * 1000, rel=5e-3)  # 3 digits
    rebuilt = page.inner_text(f'#dash-recent [data-id="{jobs["rebuilt"]["id"]}"] .headline')
    max_um = float(re.search(r"deviation max ([-\d.]+) µm", rebuilt).group(1))
    assert max_um == pytest.approx(jobs["rebuilt"]["result"]["deviation"]["max_mm"] * 1000, rel=5e-3)
    assert page.js_errors == []
