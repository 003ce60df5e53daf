"""A board job's long parameters in the console: the job's record leaves its trace ids out
(``params_omitted``), and the jobs page still shows them and runs the job again with every
one of them (it asks for ``?include=params``)."""

from __future__ import annotations

import io

import trimesh

TRACES = 700  # 700 trace ids: over the record's 16 KiB of parameters


def test_run_again_sends_every_trace_id_of_a_board_job(page, served):
    api = served.api()
    buffer = io.BytesIO()
    box = trimesh.creation.box(extents=(120, 120, 4))
    box.apply_translation([60, 60, 2])
    box.export(buffer, file_type="stl")
    part = api.post("/api/v1/parts", files={"file": ("params-box.stl", buffer.getvalue())}).json()
    body = [{"name": f"p{i}", "frame": "xy", "standoff_mm": 0.1,
             "geometry": {"type": "line", "start": [5 + (i % 35) * 3, 5 + (i // 35) * 5],
                          "end": [6.5 + (i % 35) * 3, 5 + (i // 35) * 5]}} for i in range(TRACES)]
    imported = api.post(f"/api/v1/parts/{part['id']}/traces:import", json=body)
    assert imported.status_code == 201, imported.text
    ids = [t["id"] for t in imported.json()["items"]]
    job = api.post("/api/v1/jobs", json={"kind": "probe_plan", "params": {"trace_ids": ids, "count": 40}}).json()
    api.post(f"/api/v1/jobs/{job['id']}/cancel")  # its record is what matters, not its plan
    record = api.get(f"/api/v1/jobs/{job['id']}").json()
    assert record["params_omitted"] == {"trace_ids": TRACES} and record["params"]["count"] == 40

    page.goto(f"/jobs.html?job={job['id']}")
    page.wait_for_selector(f'#job-detail[data-job-id="{job["id"]}"]')
    assert ids[0] in (page.text_content("#job-detail details pre") or "")  # the Parameters pane shows them
    page.click("#rerun-job")
    page.wait_for_selector(f'#job-detail[data-job-id]:not([data-job-id="{job["id"]}"])')  # the copy is opened
    again = page.get_attribute("#job-detail", "data-job-id")
    api.post(f"/api/v1/jobs/{again}/cancel")
    copy = api.get(f"/api/v1/jobs/{again}", params={"include": "params"}).json()
    assert copy["kind"] == "probe_plan" and copy["params"]["trace_ids"] == ids and copy["params"]["count"] == 40
    assert not page.js_errors, page.js_errors
