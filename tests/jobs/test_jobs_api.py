"""Jobs through the API: submission checks, execution, progress, SSE, cancel, artifacts."""

from __future__ import annotations

from tests.helpers.jobs import OP, wait_for


def test_submit_runs_and_records_result_and_artifact(client):
    response = client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0.05, "artifact": True}},
                           headers=OP)
    assert response.status_code == 202
    job = response.json()
    assert response.headers["location"] == f"/api/v1/jobs/{job['id']}"
    assert job["status"] in ("queued", "running", "succeeded")
    done = wait_for(client, job["id"])
    assert done["status"] == "succeeded" and done["progress"] == 1.0
    assert done["result"] == {"slept_s": 0.05, "attempt": 1}
    assert done["software_version"] and done["started_at"] and done["finished_at"]
    [artifact] = done["artifacts"]
    body = client.get(artifact["url"], headers=OP)
    assert body.status_code == 200 and body.text == f"job {job['id']} slept 0.05\n"
    import hashlib

    assert hashlib.sha256(body.content).hexdigest() == artifact["sha256"]


def test_parameters_are_checked_at_submission(client):
    unknown = client.post("/api/v1/jobs", json={"kind": "warp_drive", "params": {}}, headers=OP)
    assert unknown.status_code == 422 and unknown.json()["errors"][0]["loc"] == ["kind"]
    assert "warp_drive" in unknown.json()["detail"]
    extra = client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"sleep": 1}}, headers=OP)
    assert extra.status_code == 422 and extra.json()["errors"][0]["loc"] == ["params", "sleep"]
    bad = client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": -1}}, headers=OP)
    assert bad.status_code == 422 and bad.json()["errors"][0]["value"] == -1
    assert client.get("/api/v1/jobs", headers=OP).json()["total"] == 0  # nothing was written


def test_failed_job_carries_a_problem(client):
    job = client.post("/api/v1/jobs", json={"kind": "test_fail", "params": {"message": "no probe"}}, headers=OP).json()
    done = wait_for(client, job["id"])
    assert done["status"] == "failed"
    assert done["error"]["status"] == 422 and done["error"]["detail"] == "no probe"


def test_cancel_running_job_cooperatively_and_twice_is_409(client):
    job = client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 30, "steps": 300}},
                      headers=OP).json()
    wait_for(client, job["id"], states=("running",))
    assert client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=OP).status_code == 202
    again = client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=OP)
    assert again.status_code == 409
    done = wait_for(client, job["id"])
    assert done["status"] == "cancelled" and done["progress"] < 0.5
    after = client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=OP)
    assert after.status_code == 409 and "cancelled" in after.json()["detail"]


def test_list_filters_and_pages(client):
    ids = [client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0}}, headers=OP).json()["id"]
           for _ in range(3)]
    client.post("/api/v1/jobs", json={"kind": "test_fail"}, headers=OP)
    for job_id in ids:
        wait_for(client, job_id)
    page = client.get("/api/v1/jobs?kind=test_sleep&limit=2", headers=OP).json()
    assert page["total"] == 3 and len(page["items"]) == 2
    assert client.get("/api/v1/jobs?status=nonsense", headers=OP).status_code == 422


def test_server_sent_events_report_progress_to_the_end(client):
    job = client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0.4, "steps": 4}},
                      headers=OP).json()
    events = []
    with client.stream("GET", f"/api/v1/jobs/{job['id']}/events", headers=OP) as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        for line in stream.iter_lines():
            if line.startswith("data: "):
                import json

                events.append(json.loads(line[6:]))
    assert events[-1]["status"] == "succeeded"
    progresses = [e["progress"] for e in events if e["status"] == "running"]
    assert progresses == sorted(progresses) and len(progresses) >= 2


def test_missing_job_is_404(client):
    response = client.get("/api/v1/jobs/job_missing", headers=OP)
    assert response.status_code == 404 and "job_missing" in response.json()["detail"]
    assert client.get("/api/v1/jobs/job_missing/artifacts/x", headers=OP).status_code == 404
