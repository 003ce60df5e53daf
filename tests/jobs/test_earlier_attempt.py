"""A job's attempt runs only once the process of its earlier attempt has ended: the process
is named by pid, start time and boot, so a reused pid is never taken for it."""

from __future__ import annotations

import subprocess
import time

import pytest
from sqlmodel import Session

from app.platform.models import Job
from app.runtime.engine import Runtime
from app.runtime.process_identity import alive, identify, make_gone


@pytest.fixture
def sleeper():
    proc = subprocess.Popen(["sleep", "60"])
    yield proc
    proc.kill()
    proc.wait()


def test_a_record_names_one_process_not_its_pid(sleeper):
    record = identify(sleeper.pid)
    assert record is not None and alive(record)
    assert not alive({**record, "start_ticks": record["start_ticks"] + 1})  # the pid reused by another process
    assert not alive({**record, "boot_id": "00000000-0000-0000-0000-000000000000"})  # another boot or host
    sleeper.kill()
    time.sleep(0.2)  # a zombie now (not reaped): it computes nothing
    assert not alive(record)
    assert make_gone(record) == "gone"


def test_make_gone_waits_for_a_process_that_ends_and_kills_one_that_does_not(sleeper):
    short = subprocess.Popen(["sleep", "0.3"])
    try:
        assert make_gone(identify(short.pid), wait_s=10.0) == "exited"
    finally:
        short.wait()
    began = time.monotonic()
    assert make_gone(identify(sleeper.pid), wait_s=0.2) == "killed"
    assert sleeper.wait(5) == -9 and time.monotonic() - began < 5


def _lose_first_attempt(runtime: Runtime, record: dict) -> str:
    """A job whose first attempt's worker died while ``record``'s process ran it, requeued."""
    job = runtime.submit("test_sleep", {"seconds": 0})
    claim = runtime.store.claim(job.id, "dead-worker-1")
    assert runtime.store.record_process(claim, record)
    time.sleep(1.1)  # its lease expires
    assert job.id in runtime.store.reap(stale_enqueue_s=60)
    return job.id


def _run_to_the_end(runtime: Runtime, job_id: str) -> Job:
    runtime.start_workers(("default",))
    deadline = time.monotonic() + 60
    while runtime.store.status(job_id)[0] not in ("succeeded", "failed", "cancelled"):
        assert time.monotonic() < deadline
        time.sleep(0.05)
    with Session(runtime.engine) as session:
        return session.get(Job, job_id)


def test_the_process_of_an_earlier_attempt_is_killed_before_the_job_runs_again(runtime, sleeper):
    job_id = _lose_first_attempt(runtime, identify(sleeper.pid))
    row = _run_to_the_end(runtime, job_id)
    assert sleeper.poll() == -9  # SIGKILLed: it did not end by itself within EARLIER_WAIT_S
    assert row.status == "succeeded" and row.attempts == 2 and row.result["attempt"] == 2
    assert row.process["pid"] not in (None, sleeper.pid) and row.process["pid"] in {
        m.pid for m in runtime.supervisor.pool.members}  # the second attempt's process, recorded


def test_a_reused_pid_is_left_alone(runtime, sleeper):
    record = {**identify(sleeper.pid), "start_ticks": identify(sleeper.pid)["start_ticks"] - 1}
    row = _run_to_the_end(runtime, _lose_first_attempt(runtime, record))
    assert row.status == "succeeded" and row.attempts == 2
    assert sleeper.poll() is None
