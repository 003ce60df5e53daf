"""Page-load budget: every page interactive (its first data shown) in under a second on
localhost with 1,000 jobs and 100 parts stored — the history a lab builds in a few weeks."""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import create_engine, insert, select

from app.platform.models import Job, Part

PAGES = ["index.html", "parts.html", "traces.html", "jobs.html", "machines.html"]
BUDGET_S = 1.0
JOBS, PARTS = 1000, 100


@pytest.fixture(scope="module")
def stored_history(served) -> None:
    """Bring the served database up to 1,000 jobs and 100 parts (rows written beside the
    running server, as another process would; dated a week back so they are history)."""
    api = served.api()
    engine = create_engine(f"sqlite:///{served.data_dir / 'conforma.db'}")
    with engine.begin() as conn:
        parts = conn.execute(select(Part.__table__)).mappings().all()
    if not parts:
        import io

        import trimesh

        buffer = io.BytesIO()
        trimesh.creation.box(extents=(10, 10, 2)).export(buffer, file_type="stl")
        api.post("/api/v1/parts", files={"file": ("budget.stl", buffer.getvalue())}).raise_for_status()
        with engine.begin() as conn:
            parts = conn.execute(select(Part.__table__)).mappings().all()
    template = dict(parts[0])
    old = datetime.now(UTC) - timedelta(days=7)
    with engine.begin() as conn:
        have_parts = len(parts)
        conn.execute(insert(Part.__table__), [
            {**template, "id": f"part_budget{i:04d}", "name": f"budget part {i}", "created_at": old}
            for i in range(max(PARTS - have_parts, 0))])
        have_jobs = conn.execute(select(Job.__table__.c.id)).fetchall()
        conn.execute(insert(Job.__table__), [
            {"id": f"job_budget{i:05d}", "kind": "toolpath", "status": "succeeded", "progress": 1.0, "message": "",
             "params": {"slice_job_id": "job_x", "pattern": "lines"}, "result": {"time_s": 8276.24, "path_mm": 1234.5},
             "error": None, "parent_id": None, "queue": "default", "attempts": 1, "max_attempts": 3,
             "cancel_requested": False, "input_hashes": {}, "software_version": "test", "revision": 1,
             "created_at": old + timedelta(seconds=i), "started_at": old, "finished_at": old + timedelta(seconds=1)}
            for i in range(max(JOBS - len(have_jobs), 0))])
    engine.dispose()
    assert api.get("/api/v1/jobs?limit=1").json()["total"] >= JOBS
    assert api.get("/api/v1/parts?limit=1").json()["total"] >= PARTS


@pytest.mark.parametrize("name", PAGES)
def test_every_page_is_interactive_within_a_second(page, stored_history, name):
    """Timed by the browser: from the navigation's start (the HTML requested) to the page's
    ``conforma:ready`` mark (its first data shown).  The harness's own wall clock (which adds
    the test driver's round trips to the browser) is printed beside it."""
    timings: list[float] = []
    harness: list[float] = []
    while len(timings) < 5 and (not timings or min(timings) >= BUDGET_S):   # best of up to five: a shared machine
        start = time.perf_counter()
        page.goto(f"/{name}")
        page.wait_for_selector('body[data-ready="1"]', timeout=30_000)
        harness.append(time.perf_counter() - start)
        ready_ms = page.evaluate("performance.getEntriesByName('conforma:ready')[0]?.startTime ?? null")
        assert ready_ms is not None, f"{name} marked itself ready without the conforma:ready mark"
        timings.append(ready_ms / 1000)
    print(f"{name}: best {min(timings) * 1000:.0f} ms of {[round(t * 1000) for t in timings]} "
          f"(harness wall clock {[round(t * 1000) for t in harness]} ms)")
    assert min(timings) < BUDGET_S, (name, timings)
