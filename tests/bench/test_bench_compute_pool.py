"""Bench: long-lived compute processes ("the second job on the same 1M-face
part skips the precomputation").

Run: .venv/bin/python -m pytest tests/bench/test_bench_compute_pool.py -s -o addopts="" -q

Both services run in process isolation with the per-part disk cache on; they differ only in
``CONFORMA_COMPUTE_RECYCLE_JOBS``: 1 = a fresh process for every job (the disk tier saves
parsing, normals and the edge grid, but embree's ray structure is rebuilt by every job), the
default = one long-lived process (``worker_threads=1``) that keeps the mesh with its ray
structure and edge grid in memory.  On the 1,344,002-face S1 part, three ``probe_plan``
jobs and three draping jobs (``test_drape``: the edge grid's drape plus embree's
ray casts, through ``ctx.mesh``) each: wall and CPU seconds of the job in its process
(the journal), and started -> finished as the service saw it.  Then the overhead of a tiny
job (``test_sleep`` 0 s): created -> finished, fresh fork vs reused process.
"""

from __future__ import annotations

import statistics
from datetime import datetime
from typing import Any

import pytest

from app.parts.cache import journal
from app.reference.s1 import s1_mesh, s1_traces
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
GRID_MM = 0.06  # S1 at 0.06 mm: 1,344,002 faces
XY = [[3.0, 4.0], [20.0, 31.0], [41.5, 12.25], [57.0, 36.0]]


def _seconds(job: dict, start: str = "started_at") -> float:
    return (datetime.fromisoformat(job["finished_at"]) - datetime.fromisoformat(job[start])).total_seconds()


def _run(client, kind: str, params: dict) -> dict:  # type: ignore[no-untyped-def]
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=900)
    assert done["status"] == "succeeded", done["error"]
    return done


def _service(settings_factory, name: str, **overrides: Any):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    settings = settings_factory(worker_threads=1, job_time_s=3600, job_memory_mb=4096, lease_s=30.0, **overrides,
                                data_dir=settings_factory().data_dir.parent / name)
    return TestClient(create_app(settings), raise_server_exceptions=False), settings


def _jobs_on_the_big_part(settings_factory, name: str, data: bytes, **overrides: Any) -> list[dict]:
    client, settings = _service(settings_factory, name, **overrides)
    with client:
        part = client.post("/api/v1/parts", files={"file": ("s1.stl", data)}, headers=OP)
        assert part.status_code == 201, part.text
        trace = client.post(f"/api/v1/parts/{part.json()['id']}/traces", json=s1_traces()[4].to_api(), headers=OP)
        assert trace.status_code == 201, trace.text
        plan = {"trace_id": trace.json()["id"], "method": "uniform", "count": 8}
        drape = {"part_id": part.json()["id"], "xy": XY}
        done = []
        for _ in range(3):
            done.append(("probe_plan", _run(client, "probe_plan", plan)))
            done.append(("test_drape", _run(client, "test_drape", drape)))
    entries = {e["job_id"]: e for e in journal(settings.data_dir / "part-cache")}
    return [{"kind": kind, "job": job, "entry": entries[job["id"]]} for kind, job in done]


@pytest.mark.timeout(3600)
def test_second_and_third_jobs_on_a_1m_face_part_cold_vs_warm(settings_factory):
    data = s1_mesh(grid_mm=GRID_MM).export(file_type="stl")
    fresh = _jobs_on_the_big_part(settings_factory, "fresh", data, compute_recycle_jobs=1)
    warm = _jobs_on_the_big_part(settings_factory, "warm", data)
    print(f"\n\nS1 at {GRID_MM} mm (1,344,002 faces); each job's wall / CPU in its process "
          "(started -> finished as the service saw it):")
    print("| job | fresh process per job (disk cache) | long-lived process | warm / fresh wall, CPU |")
    print("|---|---|---|---|")
    for i, (f, w) in enumerate(zip(fresh, warm)):
        fm, wm = f["entry"]["memory"], w["entry"]["memory"]
        print(f"| {f['kind']} #{i // 2 + 1} | {fm['wall_s']:.2f} / {fm['cpu_s']:.2f} s ({_seconds(f['job']):.2f} s) "
              f"| {wm['wall_s']:.2f} / {wm['cpu_s']:.2f} s ({_seconds(w['job']):.2f} s) "
              f"| {wm['wall_s'] / fm['wall_s']:.2f}, {wm['cpu_s'] / max(fm['cpu_s'], 1e-9):.2f} |")
    later_fresh = sum(f["entry"]["memory"]["wall_s"] for f in fresh[2:])
    later_warm = sum(w["entry"]["memory"]["wall_s"] for w in warm[2:])
    print(f"jobs 2 and 3 of each kind: {later_fresh:.2f} s fresh, {later_warm:.2f} s warm "
          f"({later_warm / later_fresh:.2f}x, saved {later_fresh - later_warm:.2f} s)")
    assert all(w["entry"]["pid"] == warm[0]["entry"]["pid"] for w in warm)  # one long-lived process
    assert len({f["entry"]["pid"] for f in fresh}) == len(fresh)  # a process per job
    assert all(w["entry"]["memory"]["mesh_hits"] for w in warm[1:])
    assert later_warm < later_fresh


def test_tiny_job_overhead_fresh_fork_vs_reused_process(settings_factory):
    figures = {}
    for name, overrides in (("fork", {"compute_recycle_jobs": 1}), ("reuse", {})):
        client, _ = _service(settings_factory, f"tiny-{name}", **overrides)
        with client:
            _run(client, "test_sleep", {"seconds": 0, "steps": 1})  # the fork server and first process up
            figures[name] = [_seconds(_run(client, "test_sleep", {"seconds": 0, "steps": 1}), "created_at")
                             for _ in range(10)]
    fork, reuse = statistics.median(figures["fork"]), statistics.median(figures["reuse"])
    print(f"\n\nA tiny job (test_sleep 0 s), created -> finished, median of 10: fresh fork {fork * 1000:.0f} ms, "
          f"reused process {reuse * 1000:.0f} ms ({reuse / fork:.2f}x)")
    assert reuse < fork
