"""Create-versus-delete races, 100 rounds each, in one process with real threads: every
answer is a success, a 404 or a 409 (never a 500), and no record ever points at nothing
(jobs at deleted parts or traces, traces at deleted parts)."""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable

import pytest
import trimesh
from sqlmodel import Session, select

from app.platform.models import Job, JobReference, Part, Trace
from tests.conftest import auth

OP = auth("operator")
ROUNDS = 100
BOX = trimesh.creation.box(extents=(40.0, 40.0, 10.0)).export(file_type="stl")
LINE = {"name": "t", "geometry": {"type": "line", "start": [-10, 0], "end": [10, 0]}}


@pytest.fixture(scope="module")
def racer(tmp_path_factory):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app
    from app.platform.config import load_settings
    from tests.conftest import KEYS

    settings = load_settings({}, data_dir=tmp_path_factory.mktemp("races"), viewer=False, embedded_worker=False,
                             api_keys=",".join(f"{k}:{r}" for r, k in KEYS.items()))
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


def _together(*calls: Callable[[], int]) -> list[int]:
    """Run ``calls`` at the same moment on their own threads; their status codes."""
    barrier = threading.Barrier(len(calls))
    codes: list[int] = [0] * len(calls)

    def run(i: int) -> None:
        barrier.wait()
        codes[i] = calls[i]()

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(calls))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return codes


def _dangling(client) -> list[str]:  # type: ignore[no-untyped-def]
    engine = client.app.state.runtime.engine
    with Session(engine) as session:
        parts = set(session.exec(select(Part.id)).all())
        traces = set(session.exec(select(Trace.id)).all())
        jobs = set(session.exec(select(Job.id)).all())
        bad = [f"trace {t.id} -> part {t.part_id}" for t in session.exec(select(Trace)).all() if t.part_id not in parts]
        for ref in session.exec(select(JobReference)).all():
            known = {"part": parts, "trace": traces, "job": jobs}.get(ref.ref_kind)
            if known is not None and ref.ref_id not in known:
                bad.append(f"job {ref.job_id} -> {ref.ref_kind} {ref.ref_id}")
    return bad


def _part(client) -> str:  # type: ignore[no-untyped-def]
    response = client.post("/api/v1/parts", files={"file": ("box.stl", BOX)}, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _trace(client, part_id: str) -> str:  # type: ignore[no-untyped-def]
    response = client.post(f"/api/v1/parts/{part_id}/traces", json=LINE, headers=OP)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _plan(trace_id: str) -> dict:
    return {"kind": "probe_plan", "params": {"trace_id": trace_id, "method": "uniform", "count": 5}}


def test_delete_part_racing_create_trace(racer):  # type: ignore[no-untyped-def]
    outcomes: Counter = Counter()
    for _ in range(ROUNDS):
        part_id = _part(racer)
        delete, create = _together(
            lambda: racer.delete(f"/api/v1/parts/{part_id}", headers=OP).status_code,  # noqa: B023 (run at once)
            lambda: racer.post(f"/api/v1/parts/{part_id}/traces", json=LINE, headers=OP).status_code)  # noqa: B023 (run at once)
        outcomes[(delete, create)] += 1
        assert delete == 204 and create in (201, 404), (delete, create)
    assert _dangling(racer) == []
    print("delete part | create trace:", dict(outcomes))


def test_delete_part_racing_submit_job(racer):  # type: ignore[no-untyped-def]
    outcomes: Counter = Counter()
    for _ in range(ROUNDS):
        part_id = _part(racer)
        trace_id = _trace(racer, part_id)
        delete, submit = _together(
            lambda: racer.delete(f"/api/v1/parts/{part_id}", headers=OP).status_code,  # noqa: B023 (run at once)
            lambda: racer.post("/api/v1/jobs", json=_plan(trace_id), headers=OP).status_code)  # noqa: B023 (run at once)
        outcomes[(delete, submit)] += 1
        # exactly one wins: the job (then the part is referenced: 409) or the delete (404/422 for the job)
        assert (delete, submit) in {(409, 202), (204, 404), (204, 422)}, (delete, submit)
    assert _dangling(racer) == []
    print("delete part | submit job:", dict(outcomes))


def test_delete_trace_racing_submit_job(racer):  # type: ignore[no-untyped-def]
    outcomes: Counter = Counter()
    part_id = _part(racer)
    for _ in range(ROUNDS):
        trace_id = _trace(racer, part_id)
        delete, submit = _together(
            lambda: racer.delete(f"/api/v1/traces/{trace_id}", headers=OP).status_code,  # noqa: B023 (run at once)
            lambda: racer.post("/api/v1/jobs", json=_plan(trace_id), headers=OP).status_code)  # noqa: B023 (run at once)
        outcomes[(delete, submit)] += 1
        assert (delete, submit) in {(409, 202), (204, 404), (204, 422)}, (delete, submit)
    assert _dangling(racer) == []
    print("delete trace | submit job:", dict(outcomes))
