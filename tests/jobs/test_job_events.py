"""Progress streams (SSE) are async and capped per API key."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from tests.conftest import KEYS, auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


@pytest.fixture
def capped(settings_factory):
    with TestClient(create_app(settings_factory(sse_streams_per_key=2)), raise_server_exceptions=False) as client:
        yield client


def test_streams_beyond_the_per_key_cap_get_429_with_retry_after(capped):
    job = capped.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 3, "steps": 30}},
                      headers=OP).json()
    url = f"/api/v1/jobs/{job['id']}/events"
    with capped.stream("GET", url, headers=OP) as first, capped.stream("GET", url, headers=OP) as second:
        assert first.status_code == second.status_code == 200
        refused = capped.get(url, headers=OP)
        assert refused.status_code == 429 and int(refused.headers["retry-after"]) > 0
        assert refused.headers["content-type"].startswith("application/problem+json")
        assert "2 open progress streams" in refused.json()["detail"]
        with capped.stream("GET", url, headers=auth("viewer")) as other_key:  # the cap is per key
            assert other_key.status_code == 200
    capped.post(f"/api/v1/jobs/{job['id']}/cancel", headers=OP)
    wait_for(capped, job["id"])
    with capped.stream("GET", url, headers={"X-API-Key": KEYS["operator"]}) as again:  # slots were released
        assert again.status_code == 200
        events = [json.loads(line[6:]) for line in again.iter_lines() if line.startswith("data: ")]
    assert events[-1]["status"] == "cancelled"


def test_a_stream_of_a_missing_job_is_404_and_frees_its_slot(capped):
    for _ in range(3):
        response = capped.get("/api/v1/jobs/job_missing/events", headers=OP)
        assert response.status_code == 404 and "job_missing" in response.json()["detail"]
