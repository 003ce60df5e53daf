"""Job history: filters by part (its own jobs and its traces' jobs), machine, kind, status,
creation time and top level, with paging that stays consistent."""

from __future__ import annotations

import io
from datetime import UTC, datetime, timedelta

import trimesh
from sqlmodel import Session

from app.platform.models import JobReference
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


def _box_part(client, name: str) -> dict:
    buffer = io.BytesIO()
    trimesh.creation.box(extents=(20, 20, 5)).export(buffer, file_type="stl")
    response = client.post("/api/v1/parts", files={"file": (f"{name}.stl", buffer.getvalue())}, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()


def _trace(client, part_id: str) -> dict:
    body = {"name": "t", "geometry": {"type": "line", "start": [-5, 0], "end": [5, 0]}, "standoff_mm": 0.1}
    response = client.post(f"/api/v1/parts/{part_id}/traces", json=body, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()


def _submit(client, kind: str, params: dict) -> str:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    return response.json()["id"]


def _ids(client, query: str) -> set[str]:
    page = client.get(f"/api/v1/jobs?{query}", headers=OP).json()
    assert page["total"] == len(page["items"]), page["total"]
    return {job["id"] for job in page["items"]}


def test_filters_by_part_machine_kind_status_time_and_top_level(client):
    a, b = _box_part(client, "a"), _box_part(client, "b")
    trace_a = _trace(client, a["id"])
    plan_a = _submit(client, "probe_plan", {"trace_id": trace_a["id"], "method": "uniform", "count": 5})
    slice_b = _submit(client, "slice", {"part_id": b["id"]})
    parent = _submit(client, "test_sleep", {"seconds": 0})
    on_machine = _submit(client, "test_sleep", {"seconds": 0})
    for job_id in (plan_a, slice_b, parent, on_machine):
        wait_for(client, job_id)
    runtime = client.app.state.runtime
    with Session(runtime.engine) as session:  # what a machine job's submission records
        session.add(JobReference(job_id=on_machine, ref_kind="machine", ref_id="mach_1"))
        session.commit()
    child = runtime.submit("test_sleep", {"seconds": 0}, parent_id=parent).id
    wait_for(client, child)

    assert _ids(client, f"part_id={a['id']}") == {plan_a}         # through its trace
    assert _ids(client, f"part_id={b['id']}") == {slice_b}        # directly
    assert _ids(client, "machine_id=mach_1") == {on_machine}
    assert _ids(client, "kind=test_sleep") == {parent, on_machine, child}
    assert _ids(client, "kind=test_sleep&top_level=true") == {parent, on_machine}
    assert _ids(client, f"parent_id={parent}") == {child}
    assert _ids(client, "status=succeeded&kind=slice") == {slice_b}
    now = datetime.now(UTC)
    assert len(_ids(client, f"created_after={(now - timedelta(minutes=5)).isoformat()}".replace("+", "%2B"))) == 5
    assert _ids(client, f"created_before={(now - timedelta(minutes=5)).isoformat()}".replace("+", "%2B")) == set()
    assert _ids(client, "part_id=part_nothing") == set()


def test_paging_walks_every_job_once_newest_first(client):
    ids = [_submit(client, "test_sleep", {"seconds": 0}) for _ in range(7)]
    seen: list[dict] = []
    for offset in range(0, 7, 3):
        page = client.get(f"/api/v1/jobs?limit=3&offset={offset}", headers=OP).json()
        assert page["total"] == 7
        seen.extend(page["items"])
    assert sorted(job["id"] for job in seen) == sorted(ids)
    created = [job["created_at"] for job in seen]
    assert created == sorted(created, reverse=True)


def test_bad_filters_are_422_naming_the_parameter(client):
    response = client.get("/api/v1/jobs?created_after=yesterday", headers=OP)
    assert response.status_code == 422
    assert any("created_after" in error["loc"] for error in response.json()["errors"])
    assert client.get("/api/v1/jobs?top_level=maybe", headers=OP).status_code == 422


def test_a_jobs_artifacts_are_listed(client):
    job_id = _submit(client, "test_sleep", {"seconds": 0, "artifact": True})
    done = wait_for(client, job_id)
    listed = client.get(f"/api/v1/jobs/{job_id}/artifacts", headers=OP)
    assert listed.status_code == 200 and listed.json() == done["artifacts"] and len(listed.json()) == 1
    body = client.get(listed.json()[0]["url"], headers=OP)
    assert body.status_code == 200
    assert client.get("/api/v1/jobs/job_missing/artifacts", headers=OP).status_code == 404
    assert client.get(f"/api/v1/jobs/{job_id}/artifacts").status_code == 401
