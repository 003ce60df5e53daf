"""In a real browser: a board compensate job's result read at a glance — the summary
line, the table of traces worst first (20 rows, then all), sorting by a column, the
operator's tolerance, each trace's program downloads and the selected trace's chart.  Every
figure on screen is checked against what the API says."""

from __future__ import annotations

import pytest

from app.reference.s1 import as_made, s1_mesh, s1_traces
from tests.e2e.browser.conftest import screenshot
from tests.e2e.browser.test_result_views import duration, run

LINES = 22  # straight traces across the S1 part, plus three of its own: more than the 20 rows shown first
PROCESS = {"deviation_amplitude_mm": 0.15, "deviation_wavelength_mm": 15.0}


def um(text: str) -> float:
    """A '12.3 µm' (or '≤ 12.3 µm') cell as a number."""
    return float(text.replace("≤", "").replace("µm", "").strip())


@pytest.fixture(scope="module")
def board(served) -> dict:
    api = served.api()
    part = api.post("/api/v1/parts",
                    files={"file": ("board-s1.stl", s1_mesh(grid_mm=0.6).export(file_type="stl"))}).json()
    real = api.post("/api/v1/parts", files={"file": ("board-real.stl", as_made(seed=7, amplitude_mm=0.15).mesh(
        grid_mm=0.6).export(file_type="stl"))}).json()
    lines = [{"name": f"line-{i + 1:02d}", "frame": "xy", "standoff_mm": 0.08,
              "geometry": {"type": "line", "start": [4.0 + 2.4 * i, 5.0], "end": [4.0 + 2.4 * i, 35.0]}}
             for i in range(LINES)]
    traces = api.post(f"/api/v1/parts/{part['id']}/traces:import",
                      json=lines + [s1_traces()[i].to_api() for i in (1, 4, 8)]).json()["items"]
    machine = api.post("/api/v1/machines", json={"name": "board-view-mock", "port": "mock://", "dialect": "marlin",
                                                 "mock": {"true_part_id": real["id"], "probe_noise_mm": 0.001}}).json()
    ids = [t["id"] for t in traces]
    plan = run(api, "probe_plan", {"trace_ids": ids, "count": 16, **PROCESS}, timeout=300)
    probed = run(api, "probe_run", {"plan_job_id": plan["id"], "machine_id": machine["id"]}, timeout=300)
    rebuilt = run(api, "reconstruct", {"trace_ids": ids, "probe_run_job_id": probed["id"], "method": "field"},
                  timeout=300)
    compensated = run(api, "compensate", {"trace_ids": ids, "reconstruct_job_id": rebuilt["id"], "hold_mm": 1.0},
                      timeout=300)
    return {"traces": {t["id"]: t for t in traces}, "rebuilt": rebuilt, "compensate": compensated}


def table_rows(page) -> list[dict]:
    return page.eval_on_selector_all("#board-traces tbody tr", """rows => rows.map(r => ({
        trace: r.dataset.trace, selected: r.getAttribute('aria-selected') === 'true', cls: r.className,
        cells: Object.fromEntries([...r.querySelectorAll('td[data-key]')].map(c => [c.dataset.key, c.innerText])),
        links: [...r.querySelectorAll('button.artifact-download')].map(b => [b.dataset.artifact, b.dataset.url])}))""")


def test_board_compensation_view_lists_the_worst_traces_first_with_their_programs(page, served, board):
    job, rebuilt = board["compensate"], board["rebuilt"]
    worst = {t["trace_id"]: t["deviation"]["max_mm"] * 1000 for t in rebuilt["result"]["traces"]}
    order = sorted(worst, key=lambda t: -worst[t])
    n = len(order)
    assert n == LINES + 3 and job["result"]["board"] is True
    page.goto(f"/jobs.html?job={job['id']}")
    page.wait_for_selector("#board-traces tbody tr")
    page.wait_for_function("() => [...document.querySelectorAll('#board-traces td[data-key=time_s]')]"
                           ".every(c => c.innerText !== '—')")
    rows = table_rows(page)
    # the worst 20 first, in order of their nominal program's worst standoff error
    assert [r["trace"] for r in rows] == order[:20]
    assert page.get_attribute("#board-traces", "data-sort") == "nominal_error_um:desc"
    urls = {a["name"]: a["url"] for a in job["artifacts"]}
    by_trace = {t["trace_id"]: t for t in job["result"]["traces"]}
    api = served.api()
    for r in rows[:5]:
        entry = by_trace[r["trace"]]
        assert um(r["cells"]["nominal_error_um"]) == pytest.approx(worst[r["trace"]], rel=1e-3)
        assert um(r["cells"]["compensated_error_um"]) == pytest.approx(entry["max_chord_error_mm"] * 1000, rel=1e-3)
        assert r["cells"]["trace"] == board["traces"][r["trace"]]["name"]
        summary = api.get(f"/api/v1/jobs/{job['id']}/artifacts/{entry['print_artifact']}/summary").json()
        assert r["cells"]["time_s"] == duration(summary["time_s"])
        printed = f"print.{r['trace']}.gcode"
        assert r["links"][0] == [printed, urls[printed]] and r["links"][1][0] == f"nominal.{r['trace']}.gcode"
    # a download button fetches that trace's program
    with page.expect_download() as got:
        page.click(f'#board-traces tr[data-trace="{order[0]}"] button[data-artifact="print.{order[0]}.gcode"]')
    assert got.value.suggested_filename == f"print.{order[0]}.gcode"
    path = got.value.path()
    assert path is not None and open(path, "rb").read() == api.get(urls[f"print.{order[0]}.gcode"]).content
    # the summary: traces, the worst of all (and where)
    text = page.inner_text("#board-summary")
    assert text.startswith(f"{n} traces") and board["traces"][order[0]]["name"] in text
    assert f"{float(f'{worst[order[0]]:.4g}'):g} µm" in text
    # all rows on request
    page.click("#board-all")
    page.wait_for_selector('#board-traces[data-pending="0"]')  # every row's name and time fetched
    assert page.locator("#board-traces tbody tr").count() == n
    assert {r["cells"]["trace"] for r in table_rows(page)} == {board["traces"][t]["name"] for t in order}
    # sorted by name, ascending
    page.click('#board-traces th[data-key="trace"] button')
    names = [r["cells"]["trace"] for r in table_rows(page)]
    assert names == sorted(names, key=str.casefold) and page.get_attribute("#board-traces", "data-sort") == "trace:asc"
    # a tolerance between the best and the worst trace: the summary counts the traces over it and marks them
    tolerance = (worst[order[3]] + worst[order[4]]) / 2
    page.fill("#board-tolerance", f"{tolerance:.6f}")
    assert "over the" in page.inner_text("#board-summary")
    assert "4 nominal, 0 compensated" in page.inner_text("#board-summary")
    assert sorted(r["trace"] for r in table_rows(page) if "over-nominal" in r["cls"]) == sorted(order[:4])
    page.locator("#compensate-board-view").scroll_into_view_if_needed()
    screenshot(page, "result-compensate-board")
    assert page.js_errors == []


def test_the_selected_traces_chart_or_why_there_is_none(page, board):
    job, rebuilt = board["compensate"], board["rebuilt"]
    samples = {t["trace_id"]: t["deviation"]["samples"] for t in rebuilt["result"]["traces"]}
    worst = max(rebuilt["result"]["traces"], key=lambda t: t["deviation"]["max_mm"])["trace_id"]
    with_chart = next(t for t, s in samples.items() if len(s) >= 2)
    without = next((t for t, s in samples.items() if len(s) < 2), None)
    page.goto(f"/jobs.html?job={job['id']}")
    page.wait_for_selector("#board-traces tbody tr")
    assert table_rows(page)[0]["selected"] and table_rows(page)[0]["trace"] == worst  # the worst, at first
    page.click("#board-all")
    page.wait_for_selector('#board-traces[data-pending="0"]')  # no re-render under the click
    page.click(f'#board-traces tr[data-trace="{with_chart}"] td[data-key="trace"]')
    figure = page.wait_for_selector(f'#standoff-plot[data-trace="{with_chart}"]')
    assert int(figure.get_attribute("data-rows")) == len(samples[with_chart])
    assert figure.get_attribute("data-series") == "nominal_program_um,compensated_um"
    assert [r["trace"] for r in table_rows(page) if r["selected"]] == [with_chart]
    # the posterior band: the compensated standoff ± the field's bound for this trace, centred on it
    bound = next(t["bound_mm"] for t in rebuilt["result"]["traces"] if t["trace_id"] == with_chart)
    assert bound is not None and bound > 0                         # the field method bounds every trace
    band = page.locator(f'#standoff-plot[data-trace="{with_chart}"] polygon.band')
    assert band.count() == 1
    band_y = sorted({round(float(p.split(",")[1]), 1) for p in band.get_attribute("points").split()})
    compensated_y = {round(float(p.split(",")[1]), 1) for p in
                     page.locator("#standoff-plot polyline").nth(1).get_attribute("points").split()}
    assert len(band_y) == 2 and len(compensated_y) == 1
    assert (band_y[0] + band_y[1]) / 2 == pytest.approx(compensated_y.pop(), abs=0.15)
    assert f"± the reconstruction's bound ({bound * 1000:.2f} µm" in page.get_attribute("#standoff-plot svg",
                                                                                        "aria-label")
    if without is not None:  # a trace with fewer than two stations: the view says there is no chart, and why
        page.click(f'#board-traces tr[data-trace="{without}"] td[data-key="trace"]')
        note = page.wait_for_selector("#board-no-samples")
        assert "no chart" in note.inner_text() and page.locator("#standoff-plot").count() == 0
    assert page.js_errors == []
