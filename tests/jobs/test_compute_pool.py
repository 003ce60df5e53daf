"""Long-lived compute processes (app.runtime.compute_pool): a job on a part a process already
holds reuses what the earlier job built, with byte-identical results; cancel, recycling and
affinity keep every isolation guarantee."""

from __future__ import annotations

import json
import time
from typing import Any

import pytest

from app.parts.cache import journal
from app.reference.s1 import s1_mesh, s1_traces
from app.runtime.compute_pool import ComputePool, Member, retire_reason
from tests.conftest import auth
from tests.helpers.jobs import CANCEL_BOUND_S, wait_for

OP = auth("operator")
XY = [[3.0, 4.0], [20.0, 31.0], [41.5, 12.25], [57.0, 36.0]]


def _service(settings_factory, **overrides: Any):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from app.main import create_app

    settings = settings_factory(**overrides)
    return TestClient(create_app(settings), raise_server_exceptions=False), settings


def _job(client, kind: str, params: dict, timeout: float = 180) -> dict:  # type: ignore[no-untyped-def]
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=timeout)
    assert done["status"] == "succeeded", done["error"]
    return done


def _without_job_id(value: Any, job_id: str) -> str:
    """The result as canonical JSON text, the job's own id (in G-code headers) blanked and
    the hashes of such texts dropped: what must be byte-identical warm or cold."""
    def strip(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if not k.endswith("sha256")}
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v

    return json.dumps(strip(value), sort_keys=True).replace(job_id, "JOB")


def _program(client, job: dict) -> str:  # type: ignore[no-untyped-def]
    text = client.get(f"/api/v1/jobs/{job['id']}/artifacts/probe.gcode", headers=OP)
    assert text.status_code == 200, text.text
    return text.text.replace(job["id"], "JOB")


def test_a_warm_process_gives_byte_identical_results_and_skips_the_precomputation(settings_factory):
    client, settings = _service(settings_factory, worker_threads=1)  # one process: the second job is warm
    with client:
        part = client.post("/api/v1/parts", files={"file": ("s1.stl", s1_mesh(grid_mm=1.0).export(file_type="stl"))},
                           headers=OP).json()
        trace = client.post(f"/api/v1/parts/{part['id']}/traces", json=s1_traces()[4].to_api(), headers=OP).json()
        plan = {"trace_id": trace["id"], "method": "uniform", "count": 8}
        drape = {"part_id": part["id"], "xy": XY}
        cold_plan, cold_drape = _job(client, "probe_plan", plan), _job(client, "test_drape", drape)
        warm_plan, warm_drape = _job(client, "probe_plan", plan), _job(client, "test_drape", drape)
        assert _without_job_id(warm_plan["result"], warm_plan["id"]) == _without_job_id(cold_plan["result"],
                                                                                        cold_plan["id"])
        assert _program(client, warm_plan) == _program(client, cold_plan)
        assert json.dumps(warm_drape["result"]) == json.dumps(cold_drape["result"])  # exact floats
    entries = {e["job_id"]: e for e in journal(settings.data_dir / "part-cache")}
    first, again = entries[cold_plan["id"]], entries[warm_plan["id"]]
    assert first["memory"]["process_job"] == 1 and first["memory"]["mesh_misses"] == 1 and not first["memory"]["held"]
    assert again["pid"] == first["pid"] and again["memory"]["held"] == [part["sha256"]]
    assert again["memory"]["mesh_hits"] == 1 and not again["memory"]["mesh_misses"]
    assert not again["hits"] and not again["misses"]  # nothing read from disk: it was in memory
    drape_warm = entries[warm_drape["id"]]
    assert drape_warm["pid"] == first["pid"] and drape_warm["memory"]["mesh_hits"] == 1


def test_cancel_kills_the_process_and_a_fresh_one_takes_its_place(settings_factory):
    client, _ = _service(settings_factory, worker_threads=1)
    with client:
        before = _job(client, "test_sleep", {"seconds": 0})
        pool = client.app.state.runtime.supervisor.pool
        old = {m.pid for m in pool.members}
        spin = client.post("/api/v1/jobs", json={"kind": "test_spin", "params": {"seconds": 60}}, headers=OP).json()
        wait_for(client, spin["id"], states=("running",), timeout=60)
        time.sleep(0.3)
        asked = time.monotonic()
        assert client.post(f"/api/v1/jobs/{spin['id']}/cancel", headers=OP).status_code == 202
        assert wait_for(client, spin["id"], timeout=5)["status"] == "cancelled"
        assert time.monotonic() - asked < CANCEL_BOUND_S
        after = _job(client, "test_sleep", {"seconds": 0})
        new = {m.pid for m in pool.members}
        assert len(pool.members) == 1 and not (new & old)  # the killed process was replaced
        assert before["status"] == after["status"] == "succeeded"


def test_a_process_is_recycled_after_n_jobs_and_after_its_memory_threshold(settings_factory):
    client, settings = _service(settings_factory, worker_threads=1, compute_recycle_jobs=2)
    with client:
        done = [_job(client, "test_sleep", {"seconds": 0}) for _ in range(3)]
    pids = [{e["job_id"]: e for e in journal(settings.data_dir / "part-cache")}[j["id"]]["pid"] for j in done]
    assert pids[0] == pids[1] != pids[2]
    client, settings = _service(settings_factory, worker_threads=1, compute_recycle_mb=64,
                                data_dir=settings.data_dir.parent / "small")
    with client:  # any Python process with numpy loaded is above 64 MiB resident
        done = [_job(client, "test_sleep", {"seconds": 0}) for _ in range(2)]
    entries = {e["job_id"]: e for e in journal(settings.data_dir / "part-cache")}
    assert entries[done[0]["id"]]["pid"] != entries[done[1]["id"]]["pid"]


class _Alive:
    pid = 1
    exitcode = None


def _member(held: set[str], used: float) -> Member:
    return Member(_Alive(), None, held=frozenset(held), last_used=used)


def test_affinity_prefers_a_process_holding_the_part_but_never_waits_for_it(settings_factory):
    pool = ComputePool(settings_factory(worker_threads=3))
    a, b, c = _member({"p1"}, 3.0), _member({"p2"}, 1.0), _member(set(), 2.0)
    pool._members = [a, b, c]
    assert pool.acquire({"p2"}) is b  # holds the part
    assert pool.acquire({"p2"}) is c  # the holder is busy: the idle one used least recently, at once
    b.busy = False
    assert pool.acquire({"p9"}) is b  # no holder: least recently used
    assert pool.acquire({"p1"}) is a


def test_retire_reasons(settings_factory):
    settings = settings_factory(compute_recycle_jobs=5, compute_recycle_mb=100, job_memory_mb=100)
    member = _member(set(), 0.0)
    fine = {"fit": True, "served": 1, "rss_bytes": 50 * 2**20, "vm_bytes": 500 * 2**20, "hard_bytes": 700 * 2**20}
    assert retire_reason(settings, member, fine) is None
    assert "memory" in retire_reason(settings, member, {**fine, "fit": False})
    assert "5 jobs" in retire_reason(settings, member, {**fine, "served": 5})
    assert "resident" in retire_reason(settings, member, {**fine, "rss_bytes": 101 * 2**20})
    assert "address space" in retire_reason(settings, member, {**fine, "vm_bytes": 601 * 2**20 + 1})


@pytest.mark.parametrize("signal", [9])
def test_after_a_crash_the_pool_serves_the_next_job(settings_factory, signal):
    client, _ = _service(settings_factory, worker_threads=1)
    with client:
        crash = client.post("/api/v1/jobs", json={"kind": "test_crash", "params": {"signal": signal}}, headers=OP)
        done = wait_for(client, crash.json()["id"], timeout=120)
        assert done["status"] == "failed" and "quarantined" in done["error"]["detail"]
        assert _job(client, "test_sleep", {"seconds": 0})["status"] == "succeeded"


def test_the_warm_up_starts_the_pool_with_the_app_and_without_it_the_first_job_does(settings_factory):
    """``compute_warm_up`` on (the default): the pool holds the processes it keeps idle
    (``compute_idle_processes``) soon after the app starts, before any job; off: none until
    the first compute job, which starts one and succeeds all the same."""
    client, _ = _service(settings_factory, worker_threads=2, compute_warm_up=True, compute_idle_processes=2)
    with client:
        pool = client.app.state.runtime.supervisor.pool
        deadline = time.monotonic() + 120
        while len(pool.members) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(pool.members) == 2 and pool.started == 2
    client, _ = _service(settings_factory, worker_threads=2, compute_warm_up=False,
                                data_dir=settings_factory().data_dir.parent / "cold")
    with client:
        pool = client.app.state.runtime.supervisor.pool
        time.sleep(1.0)
        assert pool.members == [] and pool.started == 0
        assert _job(client, "test_sleep", {"seconds": 0})["status"] == "succeeded"
        assert pool.started == 1


def test_one_process_while_idle_a_second_while_two_jobs_run_at_once_then_it_ends(settings_factory, monkeypatch):
    """The default keeps ONE compute process while idle (the warm-up starts one, not
    ``worker_threads``); two jobs at once start a second (no job waits for a busy one), which
    ends after EXTRA_IDLE_S without a job: the one that stays is the one used last."""
    from app.runtime import compute_pool

    monkeypatch.setattr(compute_pool, "EXTRA_IDLE_S", 1.0)
    client, _ = _service(settings_factory, worker_threads=2, compute_warm_up=True)
    with client:
        pool = client.app.state.runtime.supervisor.pool
        deadline = time.monotonic() + 120
        while len(pool.members) < 1 and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)
        assert pool.keep == 1 and len(pool.members) == 1 and pool.started == 1
        ids = [client.post("/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 2.0}}, headers=OP
                           ).json()["id"] for _ in range(2)]
        assert [wait_for(client, i, timeout=180)["status"] for i in ids] == ["succeeded", "succeeded"]
        assert pool.started == 2
        last = max(pool.members, key=lambda m: m.last_used).pid
        deadline = time.monotonic() + 30
        while len(pool.members) > 1 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert [m.pid for m in pool.members] == [last]
        assert _job(client, "test_sleep", {"seconds": 0})["status"] == "succeeded"
        assert pool.started == 2  # the one kept serves the next job


def test_after_a_small_job_the_heap_is_left_and_after_growth_or_an_eviction_it_is_trimmed(settings_factory,
                                                                                          monkeypatch):
    """A compute process collects cycles and trims its heap after a job only when it grew by
    TRIM_GROWTH_BYTES since it last did, or its mesh cache let a part go."""
    from app.runtime import compute_child

    runtime = compute_child.ChildRuntime(settings_factory())
    try:
        resident = {"now": runtime.trimmed_rss}
        trims: list[int] = []
        monkeypatch.setattr(compute_child, "_status_bytes", lambda field: resident["now"])
        monkeypatch.setattr(compute_child, "trim_heap", lambda: trims.append(resident["now"]) or True)
        resident["now"] += compute_child.TRIM_GROWTH_BYTES // 2  # a small job's growth
        assert runtime.report()["rss_bytes"] == resident["now"] and trims == []
        resident["now"] += compute_child.TRIM_GROWTH_BYTES  # more than the bound since the last trim
        runtime.report()
        assert len(trims) == 1 and runtime.trimmed_rss == resident["now"]
        box = s1_mesh()
        runtime.meshes.put("a" * 64, box)
        runtime.meshes.put("b" * 64, box.copy())
        monkeypatch.setattr(runtime.meshes._items, "max_bytes", 0)  # the report's re-measure lets "a" go
        assert runtime.report()["held"] == ["b" * 64]
        assert len(trims) == 2
    finally:
        runtime.engine.dispose()
