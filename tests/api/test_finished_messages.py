"""A finished job never keeps the progress line of a run that did not reach its end
(a failed closed loop must not read "probing 3/17" for ever).  Checked through the API,
the way the pages read it (GET /jobs/{id}, the list, and the SSE stream's last event)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from pydantic import Field

from app.domain.errors import InvalidInput
from app.runtime.context import JobContext
from app.runtime.registry import JobParams, job_kind
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


class HalfwayParams(JobParams):
    fail_at: int = Field(3, ge=0, le=100)
    steps: int = Field(17, ge=1, le=100)


@job_kind("test_fail_halfway", HalfwayParams)
def run_fail_halfway(ctx: JobContext, params: HalfwayParams) -> dict:
    """Report "probing k/N" and fail at step ``fail_at`` (never, when it is past the end)."""
    for step in range(params.steps):
        ctx.progress(step / params.steps, f"probing {step + 1}/{params.steps}")
        if step + 1 == params.fail_at:
            raise InvalidInput(f"probe {step + 1} did not trigger", field="params.fail_at", value=params.fail_at)
    return {"steps": params.steps}


@pytest.fixture
def client(settings_factory) -> Iterator:  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    settings = settings_factory(job_plugins="tests.jobs.sample_kinds,tests.api.test_finished_messages")
    with TestClient(create_app(settings)) as test_client:
        yield test_client


def _submit(client, kind: str, params: dict) -> str:  # type: ignore[no-untyped-def]
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    return response.json()["id"]


def _listed_message(client, job_id: str) -> str:  # type: ignore[no-untyped-def]
    page = client.get("/api/v1/jobs?limit=50", headers=OP).json()
    return next(j["message"] for j in page["items"] if j["id"] == job_id)


def test_a_failed_job_says_it_failed_not_where_it_was(client):
    job_id = _submit(client, "test_fail_halfway", {"fail_at": 3})
    job = wait_for(client, job_id)
    assert job["status"] == "failed"
    assert "probing" not in job["message"] and job["message"].startswith("failed: ")
    assert "probe 3 did not trigger" in job["message"]
    assert _listed_message(client, job_id) == job["message"]
    with client.stream("GET", f"/api/v1/jobs/{job_id}/events", headers=OP) as stream:
        events = [line for line in stream.iter_lines() if line.startswith("data:")]
    assert events and "probing" not in events[-1] and "failed" in events[-1]


def test_a_succeeded_job_without_closing_words_says_done(client):
    # progress stops at 16/17 (the kind never reports 1.0): "probing 17/17" at 0.94 is stale
    job = wait_for(client, _submit(client, "test_fail_halfway", {"fail_at": 0, "steps": 17}))
    assert job["status"] == "succeeded" and job["progress"] == 1.0
    assert job["message"] == "done"


def test_closing_words_reported_at_the_end_are_kept(client):
    job = wait_for(client, _submit(client, "test_sleep", {"seconds": 0.01, "steps": 3}))
    assert job["status"] == "succeeded" and job["message"] == "step 3/3"


def test_a_cancelled_job_says_cancelled(client):
    job_id = _submit(client, "test_sleep", {"seconds": 20, "steps": 200})
    deadline = time.monotonic() + 20
    while client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()["message"] in (None, ""):
        assert time.monotonic() < deadline, "the job never reported progress"
        time.sleep(0.05)
    assert client.post(f"/api/v1/jobs/{job_id}/cancel", headers=OP).status_code == 202
    job = wait_for(client, job_id)
    assert job["status"] == "cancelled"
    assert job["message"].startswith("cancelled") and "step" not in job["message"]
