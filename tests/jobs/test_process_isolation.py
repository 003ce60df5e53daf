"""Compute jobs in child processes: memory and time limits, hard cancel, crash quarantine,
and a print on the mock (in the serve process) that none of it can stop."""

from __future__ import annotations

import time
from datetime import datetime

import pytest

from hardware.protocol import commands_sha256
from tests.api.test_machines import program_text, register, upload_program
from tests.conftest import auth
from tests.helpers.jobs import CANCEL_BOUND_S, wait_for

OP = auth("operator")


def submit(client, kind: str, **params) -> dict:
    response = client.post("/api/v1/jobs", json={"kind": kind, "params": params}, headers=OP)
    assert response.status_code == 202, response.text
    return response.json()


@pytest.fixture
def limited_client(settings_factory):
    from fastapi.testclient import TestClient

    from app.main import create_app

    # 5 s: a hog reaches its 256 MiB well inside it even on a box at load 20 (at 2 s it
    # sometimes hit the time limit first there)
    settings = settings_factory(job_memory_mb=256, job_time_s=5.0)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


def test_out_of_memory_and_crashing_jobs_fail_alone_while_a_print_runs_to_its_last_line(limited_client):
    client = limited_client
    machine = register(client, time_scale=1.0).json()
    assert client.post(f"/api/v1/machines/{machine['id']}/connect", headers=OP).json()["state"] == "idle"
    program = upload_program(client, program_text(1500)).json()  # ~16 s of motion: outlasts both jobs on a loaded box
    printing = client.post(f"/api/v1/machines/{machine['id']}/print", json={"program_id": program["id"]},
                           headers=OP).json()
    wait_for(client, printing["id"], states=("running",))
    hog = submit(client, "test_hog", mb=4096)  # 16x its 256 MiB budget
    crash = submit(client, "test_crash", signal=9)  # as the OOM killer would
    hog_done, crash_done = wait_for(client, hog["id"]), wait_for(client, crash["id"])
    # both ended while the print was still streaming...
    still = client.get(f"/api/v1/jobs/{printing['id']}", headers=OP).json()
    assert still["status"] == "running" or still["finished_at"] > max(hog_done["finished_at"],
                                                                      crash_done["finished_at"])
    assert hog_done["status"] == "failed" and hog_done["error"]["title"] == "Job exceeded its memory limit"
    assert "256 MiB" in hog_done["error"]["detail"]
    assert crash_done["status"] == "failed" and "SIGKILL" in crash_done["error"]["detail"]
    # ...and the print ran to its last line, every command exactly once
    done = wait_for(client, printing["id"], timeout=60)
    assert done["status"] == "succeeded", done["error"]
    status = client.get(f"/api/v1/machines/{machine['id']}", headers=OP).json()
    # the connect's and the program's safe_off (every program starts with its outputs off), then the program
    safe = [status["profile"]["dispense_off"], *status["profile"]["outputs_off"]]
    assert status["mock"]["executed_commands"] == 2 * len(safe) + program["commands"]
    assert status["mock"]["executed_sha256"] == commands_sha256([*safe, *safe, *program_text(1500).splitlines()]).sha256


def test_cancel_kills_a_loop_that_never_checks_within_a_second(client):
    job = submit(client, "test_spin", seconds=60)
    wait_for(client, job["id"], states=("running",))
    time.sleep(0.3)  # well inside the loop
    asked = time.monotonic()
    assert client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=OP).status_code == 202
    done = wait_for(client, job["id"], timeout=5)
    assert done["status"] == "cancelled"
    assert time.monotonic() - asked < CANCEL_BOUND_S


def test_a_cancel_while_the_job_waits_for_its_process_takes_effect_at_once(client, monkeypatch):
    """The pool needs seconds to find the job a process (the first start imports the compute
    core): a cancel meanwhile ends the job within a second, and the process found afterwards
    never receives it."""
    from app.runtime.compute_pool import ComputePool

    acquire, give_back, given = ComputePool.acquire, ComputePool.give_back, []

    def slow_acquire(self, parts):
        time.sleep(3.0)
        return acquire(self, parts)

    def recorded_give_back(self, member):
        given.append(member)
        give_back(self, member)

    monkeypatch.setattr(ComputePool, "acquire", slow_acquire)
    monkeypatch.setattr(ComputePool, "give_back", recorded_give_back)
    job = submit(client, "test_spin", seconds=60)
    wait_for(client, job["id"], states=("running",))
    asked = time.monotonic()
    assert client.post(f"/api/v1/jobs/{job['id']}/cancel", headers=OP).status_code == 202
    done = wait_for(client, job["id"], timeout=5)
    assert time.monotonic() - asked < CANCEL_BOUND_S
    assert done["status"] == "cancelled"
    assert "before it reached a compute process" in done["error"]["detail"]
    deadline = time.monotonic() + 10
    while not given and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(given) == 1 and given[0].alive() and not given[0].busy  # idle again, never sent the job
    assert given[0] in client.app.state.runtime.supervisor.pool.members
    assert client.get(f"/api/v1/jobs/{job['id']}", headers=OP).json()["status"] == "cancelled"


def test_a_job_past_its_time_limit_is_killed_and_failed(limited_client):
    job = submit(limited_client, "test_spin", seconds=60)
    done = wait_for(limited_client, job["id"], timeout=20)
    assert done["status"] == "failed" and done["error"]["title"] == "Job exceeded its time limit"
    assert "5 s" in done["error"]["detail"]
    assert 5.0 <= (datetime.fromisoformat(done["finished_at"])
                   - datetime.fromisoformat(done["started_at"])).total_seconds()


def test_a_job_that_kills_its_process_is_quarantined_after_one_crash(client):
    job = submit(client, "test_crash", signal=11)
    done = wait_for(client, job["id"])
    assert done["status"] == "failed" and done["attempts"] == 1
    assert "SIGSEGV" in done["error"]["detail"] and "quarantined" in done["error"]["detail"]
    time.sleep(1.0)  # five reaper passes (reaper_interval_s 0.2): never claimed again
    again = client.get(f"/api/v1/jobs/{job['id']}", headers=OP).json()
    assert again["status"] == "failed" and again["attempts"] == 1


def test_a_job_killed_for_memory_fails_once_with_the_reason_when_the_database_first_refuses_the_write(
        client, monkeypatch):
    """The kernel's OOM killer's SIGKILL, recorded while the database is briefly locked: the job
    fails at its first attempt with the reason, never runs again as attempt 2 without an error."""
    from sqlalchemy.exc import OperationalError

    from app.runtime.store import JobStore

    finish, refused = JobStore.finish, []

    def locked_once(self, claim, status, **kwargs):
        if status == "failed" and not refused:
            refused.append(claim.job_id)
            raise OperationalError("UPDATE jobs", {}, Exception("database is locked"))
        return finish(self, claim, status, **kwargs)

    monkeypatch.setattr(JobStore, "finish", locked_once)
    job = submit(client, "test_crash", signal=9)
    done = wait_for(client, job["id"], timeout=30)
    assert refused == [job["id"]]
    assert done["status"] == "failed" and done["attempts"] == 1, done
    assert "SIGKILL" in done["error"]["detail"] and "out of memory" in done["error"]["detail"]
    time.sleep(6.0)  # past the test lease (5 s) and many reaper passes: never claimed again
    again = client.get(f"/api/v1/jobs/{job['id']}", headers=OP).json()
    assert again["status"] == "failed" and again["attempts"] == 1


def test_a_compute_job_whose_worker_is_lost_twice_is_quarantined(runtime):
    job = runtime.submit("test_sleep", {"seconds": 0})
    runtime.store.claim(job.id, "dead-worker-1")
    time.sleep(1.1)
    assert runtime.store.quarantine_lost_compute_jobs() == []  # once: a restart, requeued
    assert job.id in runtime.store.reap(stale_enqueue_s=60)
    assert runtime.store.claim(job.id, "dead-worker-2").attempt == 2
    time.sleep(1.1)
    assert runtime.store.quarantine_lost_compute_jobs() == [job.id]  # twice: suspected, not re-claimed
    runtime.store.reap(stale_enqueue_s=60)
    assert runtime.store.status(job.id)[0] == "failed"
    assert runtime.store.claim(job.id, "w3") is None


def test_a_stopping_worker_kills_its_child_and_puts_the_job_back(runtime):
    job = runtime.submit("test_spin", {"seconds": 60})
    runtime.start_workers(("default",))
    deadline = time.monotonic() + 20
    while runtime.store.status(job.id)[0] != "running":
        assert time.monotonic() < deadline
        time.sleep(0.02)
    runtime.stop()
    from sqlmodel import Session

    from app.platform.models import Job

    with Session(runtime.engine) as session:
        row = session.get(Job, job.id)
    assert row.status == "queued" and row.attempts == 0 and row.message == "released by a stopping worker"


@pytest.mark.parametrize("threads", [1, 2])
def test_a_compute_process_runs_with_the_configured_blas_threads(settings_factory, threads):
    """CONFORMA_BLAS_THREADS is applied once in the job's process (the core never sets it)."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    with TestClient(create_app(settings_factory(blas_threads=threads)), raise_server_exceptions=False) as client:
        done = wait_for(client, submit(client, "test_blas_threads")["id"], timeout=60)
    assert done["status"] == "succeeded", done
    assert done["result"]["num_threads"] == [threads]


def test_a_parent_that_loses_its_lease_leaves_its_children_alone(runtime):
    """Only an operator's cancel reaches a workflow's children: an attempt that lost its lease
    (another attempt takes over and reuses them) must not cancel a child, e.g. an interrupted
    probe run that holds measured points waiting for the operator's resume."""
    from sqlmodel import Session

    from app.domain.errors import Cancelled
    from app.platform.models import Job
    from app.runtime.context import JobContext

    parent = runtime.submit("test_sleep", {"seconds": 0})
    claim = runtime.store.claim(parent.id, "w1")
    children = [runtime.submit("test_sleep", {"seconds": 0}, parent_id=parent.id) for _ in range(2)]
    ctx = JobContext(runtime, claim)
    ctx.lost_event.set()
    with pytest.raises(Cancelled):
        ctx.wait_for([c.id for c in children], poll_s=0.01)
    with Session(runtime.engine) as session:
        assert [session.get(Job, c.id).cancel_requested for c in children] == [False, False]
        assert [session.get(Job, c.id).status for c in children] == ["queued", "queued"]
    ctx.lost_event.clear()
    ctx.cancel_event.set()  # the operator's cancel does reach them
    with pytest.raises(Cancelled):
        ctx.wait_for([c.id for c in children], poll_s=0.01)
    with Session(runtime.engine) as session:
        assert [session.get(Job, c.id).status for c in children] == ["cancelled", "cancelled"]
