"""Idle queue consumers sleep until this process enqueues (no polling); a submitted job starts
at once, and work enqueued behind their back is found by the fallback poll."""

from __future__ import annotations

import statistics
import threading
import time

import pytest
from sqlmodel import Session

from app.platform.db import migrate
from app.platform.models import Job
from app.runtime.engine import QUEUES, QueueWake, Runtime


@pytest.fixture
def runtime(settings_factory):
    settings = settings_factory(compute_isolation="thread", queue_poll_s=1.0)
    migrate(settings)
    runtime = Runtime(settings)
    runtime.start_workers()
    yield runtime
    runtime.stop()


def _wakeups(runtime: Runtime) -> int:
    return sum(runtime.wakes[name].wakeups for name in QUEUES)


def _finished(runtime: Runtime, job_id: str, timeout_s: float = 10.0) -> Job:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with Session(runtime.engine) as session:
            job = session.get(Job, job_id)
            assert job is not None
            if job.status in ("succeeded", "failed", "cancelled"):
                return job
        time.sleep(0.002)
    raise AssertionError(f"job {job_id} did not finish in {timeout_s} s")


def test_idle_workers_wake_about_once_per_fallback_poll(runtime):
    threads = sum(consumer.workers for consumer in runtime._consumers)
    time.sleep(0.3)  # the workers found the queues empty and sleep
    before = _wakeups(runtime)
    time.sleep(2.0)
    woken = _wakeups(runtime) - before
    # each worker wakes once per queue_poll_s (1 s): 2 or 3 times in 2 s; the old 20 ms poll woke it 100 times
    assert woken <= 3 * threads, (woken, threads)


def test_a_submitted_job_starts_at_once_not_at_the_fallback_poll(runtime):
    time.sleep(1.2)  # every worker sleeps on the 1 s fallback
    waits = []
    for _ in range(5):
        started = time.monotonic()
        job = runtime.submit("test_sleep", {"seconds": 0})
        done = _finished(runtime, job.id)
        waits.append(time.monotonic() - started)
        assert done.status == "succeeded"
        time.sleep(0.3)  # the workers are idle again
    # the fallback poll alone would take 0.5 s on average; a wake-up takes milliseconds
    assert statistics.median(waits) < 0.2, waits


def test_a_job_enqueued_without_a_wake_is_found_by_the_fallback_poll(settings_factory):
    settings = settings_factory(compute_isolation="thread", queue_poll_s=0.3)
    migrate(settings)
    runtime = Runtime(settings)
    runtime.start_workers()
    try:
        time.sleep(0.5)
        runtime.wakes["default"].notify = lambda everyone=False: None  # type: ignore[method-assign]
        job = runtime.submit("test_sleep", {"seconds": 0})  # as if another process had enqueued it
        assert _finished(runtime, job.id, timeout_s=5.0).status == "succeeded"
    finally:
        runtime.stop()


def test_a_wake_given_before_the_worker_sleeps_is_not_lost():
    wake, stop = QueueWake(), threading.Event()
    ticket = wake.ticket()  # the worker read the queue (empty) ...
    wake.notify()  # ... a job is enqueued before it goes to sleep
    started = time.monotonic()
    wake.wait(ticket, 5.0, stop)
    assert time.monotonic() - started < 0.5


def test_stop_wakes_a_sleeping_worker():
    wake, stop = QueueWake(), threading.Event()
    sleeper = threading.Thread(target=wake.wait, args=(wake.ticket(), 30.0, stop))
    sleeper.start()
    time.sleep(0.05)
    stop.set()
    wake.notify(everyone=True)
    sleeper.join(2.0)
    assert not sleeper.is_alive()
