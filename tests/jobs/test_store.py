"""The job table's conditional transitions, leases and the reaper."""

from __future__ import annotations

import time
from datetime import datetime

import pytest
from sqlmodel import Session

from app.api.routes.jobs import job_out
from app.platform.db import migrate
from app.platform.models import Job, utcnow
from app.runtime.engine import Runtime
from app.runtime.store import LOST_LEASE_REASON


@pytest.fixture
def runtime(settings_factory):
    settings = settings_factory(lease_s=1.0, max_attempts=2)
    migrate(settings)
    runtime = Runtime(settings)
    yield runtime
    runtime.stop()


def test_only_one_worker_can_claim(runtime):
    job = runtime.submit("test_sleep", {"seconds": 0})
    first = runtime.store.claim(job.id, "w1")
    assert first is not None and first.attempt == 1
    assert runtime.store.claim(job.id, "w2") is None


def test_lost_lease_is_requeued_then_failed_after_max_attempts(runtime):
    job = runtime.submit("test_sleep", {"seconds": 0})
    claim = runtime.store.claim(job.id, "dead-worker")
    assert runtime.store.reap(stale_enqueue_s=60) == []  # lease still valid
    time.sleep(1.1)
    assert job.id in runtime.store.reap(stale_enqueue_s=60)
    # the dead worker's late report is refused: it no longer owns the job
    assert runtime.store.heartbeat(claim, 0.5) is None
    assert runtime.store.finish(claim, "succeeded", result={}) is False
    second = runtime.store.claim(job.id, "w2")
    assert second.attempt == 2
    time.sleep(1.1)
    runtime.store.reap(stale_enqueue_s=60)
    status, _ = runtime.store.status(job.id)
    assert status == "failed"


def test_a_job_run_again_after_a_lost_lease_keeps_why_its_first_attempt_ended(runtime):
    """Never run again silently: the record of a job that succeeded on its second attempt
    still says that the first ended without finishing, and why."""
    job = runtime.submit("test_sleep", {"seconds": 0})
    runtime.store.claim(job.id, "dead-worker")
    time.sleep(1.1)
    assert job.id in runtime.store.reap(stale_enqueue_s=60)
    second = runtime.store.claim(job.id, "w2")
    assert second is not None and second.attempt == 2
    runtime.store.heartbeat(second, 0.5, message="running again")
    assert runtime.store.finish(second, "succeeded", result={"ok": True})
    with Session(runtime.engine) as session:
        row = session.get(Job, job.id)
    assert row.status == "succeeded" and row.attempts == 2
    assert len(row.earlier_attempts) == 1
    first = row.earlier_attempts[0]
    assert first["attempt"] == 1 and first["reason"] == LOST_LEASE_REASON
    assert datetime.fromisoformat(first["ended_at"]) <= utcnow()
    assert job_out(row, []).earlier_attempts == row.earlier_attempts  # what GET /jobs/{id} shows


def test_a_job_that_ran_once_has_no_earlier_attempts(runtime):
    job = runtime.submit("test_sleep", {"seconds": 0})
    claim = runtime.store.claim(job.id, "w1")
    assert runtime.store.finish(claim, "succeeded", result={})
    with Session(runtime.engine) as session:
        assert session.get(Job, job.id).earlier_attempts is None


def test_a_reaper_pass_reads_before_it_writes(runtime):
    """The pass's one read says whether there is anything to reap: nothing while the lease
    holds and the enqueue is fresh; a lost lease, or a queued job whose enqueue went stale."""
    job = runtime.submit("test_sleep", {"seconds": 0})
    assert not runtime.store.reap_due(stale_enqueue_s=60)  # queued, just enqueued
    assert runtime.store.reap_due(stale_enqueue_s=-1)  # ...its enqueue called stale
    runtime.store.claim(job.id, "dead-worker")
    assert not runtime.store.reap_due(stale_enqueue_s=60)  # running, lease valid
    assert runtime.reap_once() == []
    time.sleep(1.1)
    assert runtime.store.reap_due(stale_enqueue_s=60)  # the lease ran out
    assert runtime.reap_once() == [job.id] and runtime.store.status(job.id)[0] == "queued"


def test_cancel_of_queued_job_is_immediate(runtime):
    job = runtime.submit("test_sleep", {"seconds": 0})
    assert runtime.store.request_cancel(job.id) == "cancelled"
    assert runtime.store.request_cancel(job.id) is None
    assert runtime.store.claim(job.id, "w1") is None


def test_reaped_job_finishes_on_a_live_worker(runtime):
    job = runtime.submit("test_sleep", {"seconds": 0.05})
    runtime.store.claim(job.id, "crashed-worker")  # claimed, then the process "died"
    runtime.start_workers(("default",))
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and runtime.store.status(job.id)[0] != "succeeded":
        time.sleep(0.05)
    assert runtime.store.status(job.id)[0] == "succeeded"


def test_a_result_that_asks_for_attention_ends_the_job_in_that_state_with_its_closing_words(runtime):
    from sqlmodel import Session

    from app.platform.models import Job
    from app.runtime.store import completed_status

    assert completed_status({"needs_attention": True}) == "needs_attention"
    assert completed_status({"needs_attention": False}) == completed_status({}) == "succeeded"
    job = runtime.submit("test_sleep", {"seconds": 0})
    claim = runtime.store.claim(job.id, "w1")
    runtime.store.heartbeat(claim, 1.0, "3/3 traces done; NEEDS ATTENTION: a step")
    assert runtime.store.finish(claim, "needs_attention", result={"needs_attention": True})
    with Session(runtime.engine) as session:
        done = session.get(Job, job.id)
        assert (done.status, done.progress, done.message) == ("needs_attention", 1.0,
                                                              "3/3 traces done; NEEDS ATTENTION: a step")
        assert done.finished_at is not None and done.lease_until is None
    assert runtime.store.claim(job.id, "w2") is None          # terminal: never run again


def test_a_result_is_encoded_once_and_its_size_is_its_stored_json():
    """:func:`encoded_result` gives the plain result and the size of the JSON that plain
    result encodes to (what ``finish`` records as ``result_bytes``), numpy values included."""
    import json

    import numpy as np

    from app.runtime.store import encoded_result, json_result

    result = {"traces": [{"points": np.linspace(0.0, 1.0, 7).reshape(-1, 1) * [1.0, 2.0, np.pi],
                          "max_um": np.float64(3.25), "count": np.int64(12), "name": "t\u00e9\"1"}],
              "nan": float("nan"), "ok": True, "none": None}
    plain, size = encoded_result(result)
    assert json.dumps(plain) == json.dumps(json_result(result)) and plain["traces"][0]["points"][6][2] == np.pi
    assert size == len(json.dumps(plain).encode())
    assert encoded_result(None) == ({}, 2)


def test_a_parent_reads_its_childrens_states_less_often_the_longer_they_run(runtime, monkeypatch):
    """``wait_for`` reads the states ``poll_s`` after the first read, each wait then
    WAIT_POLL_GROWTH times the one before up to ``max_poll_s``; it returns the children once
    they are finished (here: after the seventh read)."""
    from types import SimpleNamespace

    from app.runtime import context as context_module
    from app.runtime.context import WAIT_POLL_GROWTH, JobContext

    parent = runtime.submit("test_sleep", {"seconds": 0})
    ctx = JobContext(runtime, runtime.store.claim(parent.id, "w1"))
    child = runtime.submit("test_sleep", {"seconds": 0}, parent_id=parent.id)
    child_claim = runtime.store.claim(child.id, "w2")
    waits: list[float] = []

    def sleep(seconds: float) -> None:  # the child ends during the sixth wait
        waits.append(seconds)
        if len(waits) == 6:
            assert runtime.store.finish(child_claim, "succeeded", result={"n": 1})

    monkeypatch.setattr(context_module, "time", SimpleNamespace(sleep=sleep))  # this module's waits only
    [done] = ctx.wait_for([child.id], poll_s=0.05, max_poll_s=0.2)
    assert done.id == child.id and done.status == "succeeded" and done.result == {"n": 1}
    expected = [0.05, 0.05 * WAIT_POLL_GROWTH, 0.05 * WAIT_POLL_GROWTH ** 2, 0.05 * WAIT_POLL_GROWTH ** 3, 0.2, 0.2]
    assert waits == pytest.approx(expected)


def test_a_compute_process_writes_progress_below_one_at_most_every_quarter_second(runtime, monkeypatch):
    """Where the runtime sets ``progress_every_s`` (a compute process's), progress below 1
    reported sooner than that after the job's start or the last written one is not written; the
    closing words at progress 1 always are, and a cancel is still seen."""
    from sqlmodel import Session

    from app.domain.errors import Cancelled
    from app.platform.models import Job
    from app.runtime.compute_child import PROGRESS_EVERY_S
    from app.runtime.context import JobContext

    def stored(job_id: str) -> tuple[float, str | None]:
        with Session(runtime.engine) as session:
            job = session.get(Job, job_id)
            return job.progress, job.message

    job = runtime.submit("test_sleep", {"seconds": 0})
    monkeypatch.setattr(runtime, "progress_every_s", PROGRESS_EVERY_S, raising=False)
    ctx = JobContext(runtime, runtime.store.claim(job.id, "w1"))
    ctx.progress(0.5, "halfway")
    assert stored(job.id) == (0.0, "")  # within the first quarter second: not written
    ctx._progress_at -= PROGRESS_EVERY_S  # a quarter second later
    ctx.progress(0.6, "further")
    ctx.progress(0.7, "soon after")
    assert stored(job.id) == (0.6, "further")
    ctx.progress(1.0, "3/3 done")
    assert stored(job.id) == (1.0, "3/3 done")
    ctx.cancel_event.set()
    with pytest.raises(Cancelled):
        ctx.progress(0.8)
    other = runtime.submit("test_sleep", {"seconds": 0})
    monkeypatch.delattr(runtime, "progress_every_s")  # a runtime of jobs in threads: every report written
    JobContext(runtime, runtime.store.claim(other.id, "w1")).progress(0.5, "halfway")
    assert stored(other.id) == (0.5, "halfway")
