"""The operator's main flow in a real browser: upload a part, draw a trace, plan probes,
reconstruct from measured points, follow the jobs live, and check the 3D view."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from app.reference.s1 import as_made, s1_mesh, s1_traces
from app.viewer.colors import PALETTE
from tests.e2e.browser.conftest import screenshot, screenshot_path
from tests.e2e.browser.pixels import save_view_panel, wait_for_view

TRACE = s1_traces()[6].to_api()  # a cubic NURBS across the S1 part
CURVE_ORANGE = PALETTE.reconstructed


@pytest.fixture(scope="module")
def s1_stl(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("parts") / "s1.stl"
    path.write_bytes(s1_mesh(grid_mm=1.0).export(file_type="stl"))
    return str(path)


def wait_job(api, job_id: str, timeout: float = 30.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = api.get(f"/api/v1/jobs/{job_id}?include=result&include=artifacts").json()
        if job["status"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not finish")


def submit_job_form(page, kind: str, values: dict[str, str]) -> str:
    before = page.get_attribute("#job-detail", "data-job-id")
    page.select_option("#job-kind", kind)
    page.wait_for_selector(f'#job-form-body[data-kind="{kind}"]')
    for name, value in values.items():
        page.fill(f"#param-{name}", value)
    page.click("#submit-job")
    # selectors, not wait_for_function: the pages' CSP forbids the eval that the latter needs
    changed = f':not([data-job-id="{before}"])' if before else ""
    page.wait_for_selector(f"#job-detail[data-job-id]{changed}", state="attached")
    return page.get_attribute("#job-detail", "data-job-id")


def test_upload_trace_probe_reconstruct_and_view(page, served, s1_stl):
    api = served.api()
    # -- parts: upload with progress, the new part listed
    page.goto("/parts.html")
    page.set_input_files("#part-file", s1_stl)
    page.fill("#part-name", "S1 browser")
    page.click("#upload-button")
    row = page.wait_for_selector("#parts-body tr.selected")
    part_id = row.get_attribute("data-id")
    assert "S1 browser" in row.inner_text()
    assert page.input_value("#part-name") == ""  # the form was reset after success
    screenshot(page, "parts")

    # -- traces: a NURBS trace from the form
    page.goto(f"/traces.html?part={part_id}")
    page.fill("#name", TRACE["name"])
    page.select_option("#type", "nurbs")
    page.fill("#points", "\n".join(f"{x}, {y}" for x, y in TRACE["geometry"]["control_points"]))
    page.fill("#degree", "3")
    page.click("#create-trace")
    trace_row = page.wait_for_selector("#traces-body tr.selected")
    trace_id = trace_row.get_attribute("data-id")
    trace = api.get(f"/api/v1/traces/{trace_id}").json()
    assert trace["geometry"]["control_points"] == TRACE["geometry"]["control_points"]
    screenshot(page, "traces")

    # -- jobs: probe plan from the generated form, followed live until it succeeds
    page.goto(f"/jobs.html?kind=probe_plan&trace_id={trace_id}")
    page.wait_for_selector("#param-trace_id")
    assert page.input_value("#param-trace_id") == trace_id  # prefilled from the link
    page.select_option("#param-method", '"deviation"')
    page.click("#submit-job")
    page.wait_for_selector("#job-detail[data-job-id]")
    plan_id = page.get_attribute("#job-detail", "data-job-id")
    page.wait_for_selector(f'#jobs-body tr[data-id="{plan_id}"] [data-status="succeeded"]')
    plan = api.get(f"/api/v1/jobs/{plan_id}?include=result&include=artifacts").json()

    # points "measured" on the as-made part, computed here
    truth = as_made(seed=3, amplitude_mm=0.15)
    xy = np.asarray(plan["result"]["points"])[:, :2]
    measured = np.column_stack([xy, truth.true_height(xy)]).round(6)
    rec_id = submit_job_form(page, "reconstruct", {"trace_id": trace_id, "points": json.dumps(measured.tolist())})
    page.wait_for_selector(f'#jobs-body tr[data-id="{rec_id}"] [data-status="succeeded"]')
    page.wait_for_selector("#deviation-plot")  # the detail refreshed when the stream ended
    rec = api.get(f"/api/v1/jobs/{rec_id}?include=result&include=artifacts").json()
    shown = json.loads(page.get_attribute("#deviation-plot", "data-samples"))
    assert np.allclose(shown, rec["result"]["deviation"]["samples"])
    screenshot(page, "jobs")

    # -- 3D view: the job's scene pushed, the canvas drawn, the deviation plot's data
    page.click("#open-3d")
    page.wait_for_selector("#viewer-panel[data-generation]", state="attached")
    view_id = page.get_attribute("#viewer-panel", "data-view")  # the page's own view (token-opened)
    scene = api.get("/api/v1/viewer/scene", params={"view_id": view_id}).json()
    assert scene["focus"] == {"job_id": rec_id, "part_id": part_id}
    nodes = scene["nodes"]
    assert nodes["/focus/part"]["count"] == 5400
    assert any(n.startswith("/focus/traces/") for n in nodes)
    assert any(n.startswith("/focus/curves/") for n in nodes)
    measured_node = next(v for k, v in nodes.items() if k.endswith("/measured"))
    assert measured_node["count"] == len(measured)
    plot = scene["plots"][f"deviation/{TRACE['name']}"]
    samples = np.asarray(rec["result"]["deviation"]["samples"])
    assert np.allclose(plot["x"], samples[:, 0]) and np.allclose(plot["y"], samples[:, 1])
    assert plot["x_label"] == "mm along the trace"

    frame = page.frame_locator("#viewer-iframe")
    # the canvas itself (viser's panel masked): the slate part and the rebuilt curve's orange
    counts, _img = wait_for_view(page, lambda c: c.slate > 0.02 * c.total and c.exact[CURVE_ORANGE] >= 20,
                                 exact=(CURVE_ORANGE,))
    assert counts.slate > 0.02 * counts.total and counts.exact[CURVE_ORANGE] >= 20, f"the 3D view looks blank: {counts}"
    # viser's own panel shows the uPlot deviation plot (it renders a little after the canvas)
    def plot_shown() -> bool:
        return frame.locator(".uplot").count() >= 1 or frame.get_by_text("Deviation").count() >= 1

    deadline = time.monotonic() + 15
    while not plot_shown() and time.monotonic() < deadline:
        page.wait_for_timeout(250)
    assert plot_shown()
    save_view_panel(page, screenshot_path("view3d"))
    assert page.js_errors == []
