"""The job table's conditional transitions, leases and the reaper."""

from __future__ import annotations

import time

import pytest

from app.platform.db import migrate
from app.runtime.engine import Runtime


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
