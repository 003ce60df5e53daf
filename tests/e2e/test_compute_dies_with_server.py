"""`conforma serve` SIGKILLed during a compute job: its compute processes (and their fork
server) die with it within 2 s, and after a restart the job runs once more, alone, to its end."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import httpx

from app.runtime.process_identity import identify, make_gone
from tests.e2e.test_serve import env_for, start
from tests.helpers.processes import free_port, stop, wait_healthy

KEY = "e2e-operator-key-1"
HEADERS = {"Authorization": f"Bearer {KEY}"}


def _session_members(sid: int) -> list[int]:
    """Live processes (not zombies) of session ``sid``."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if fields[0] != "Z" and int(fields[3]) == sid:
            out.append(int(entry))
    return out


def _is_compute(pid: int) -> bool:
    """A process forked by a fork server (a compute or import process), not the server itself."""
    try:
        parent = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        return b"forkserver" in Path(f"/proc/{parent}/cmdline").read_bytes()
    except (OSError, ValueError):
        return False


def _wait_job(base: str, job_id: str, states: tuple[str, ...], timeout: float = 60) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = httpx.get(f"{base}/api/v1/jobs/{job_id}?include=result&include=artifacts", headers=HEADERS,
                        timeout=10).json()
        if job["status"] in states:
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} never reached {states}: {job}")


def test_compute_processes_die_with_the_server_and_the_job_runs_once_after_restart(tmp_path):
    data = tmp_path / "data"
    env = env_for(data, CONFORMA_API_KEYS=f"{KEY}:operator", CONFORMA_LEASE_S="2")
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    server = start(["serve", "--port", str(port)], env, tmp_path / "serve.log")
    try:
        wait_healthy(base, server, log=tmp_path / "serve.log")
        # the first attempt spins on until the server's death ends it; the re-run after the restart is short
        spin = {"seconds": 60, "later_seconds": 0.5}
        job = httpx.post(f"{base}/api/v1/jobs", json={"kind": "test_spin", "params": spin}, headers=HEADERS,
                         timeout=30).json()
        _wait_job(base, job["id"], ("running",))
        assert len(_session_members(server.pid)) >= 2  # the server and its compute process(es)
        os.kill(server.pid, signal.SIGKILL)
        server.wait()
        time.sleep(2.0)
        left = [pid for pid in _session_members(server.pid) if _is_compute(pid)]
        assert left == [], "a compute process outlived the server by 2 s"
    finally:
        stop(server)
    _restart_and_finish_on_the_second_attempt(port, env, tmp_path, job["id"])


def test_a_compute_process_that_outlives_its_server_is_ended_before_the_job_runs_again(tmp_path):
    """The first execution of ``test_stubborn`` defeats both of a compute process's bonds to
    its server (no parent-death signal, the watching thread starved of the GIL): after a
    SIGKILL of the server it computes on.  The restarted server's worker ends it before it
    runs the job again, so the job's one complete execution is the second, alone."""
    data = tmp_path / "data"
    journal = tmp_path / "journal.txt"
    # a 5 s lease: a restarting server on a loaded box can stall its renewals for 2 s
    env = env_for(data, CONFORMA_API_KEYS=f"{KEY}:operator", CONFORMA_LEASE_S="5")
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    server = start(["serve", "--port", str(port)], env, tmp_path / "serve.log")
    try:
        wait_healthy(base, server, log=tmp_path / "serve.log")
        job = httpx.post(f"{base}/api/v1/jobs", json={"kind": "test_stubborn", "params": {
            "journal": str(journal), "stubborn_s": 120, "seconds": 0.5}}, headers=HEADERS, timeout=30).json()
        _wait_job(base, job["id"], ("running",))
        deadline = time.monotonic() + 30
        while not journal.exists() or not journal.read_text().endswith("\n"):
            assert time.monotonic() < deadline, "the job never started"
            time.sleep(0.05)
        first = int(journal.read_text().split()[1])
        first_record = identify(first)
        os.kill(server.pid, signal.SIGKILL)
        server.wait()
        time.sleep(2.0)
        assert first in _session_members(server.pid), "the stubborn process died with its server: nothing tested"
    finally:
        stop(server)
    _restart_and_finish_on_the_second_attempt(port, env, tmp_path, job["id"])
    assert make_gone(first_record, 0.0) == "gone", "the stubborn process outlived the restarted server"
    lines = journal.read_text().splitlines()
    assert [line.split()[0] for line in lines] == ["start", "start", "end"], lines
    second = lines[1].split()
    assert second[2] == "2" and second[3] == "-", lines  # attempt 2 began with no earlier process alive
    assert lines[2] == f"end {second[1]}"  # the one execution to its end is the second
    assert first not in _session_members(server.pid)


def _restart_and_finish_on_the_second_attempt(port: int, env: dict, tmp_path, job_id: str) -> None:
    """Start the server again on the same data and port: the job ends ``succeeded`` on its
    second attempt; the server is stopped afterwards."""
    base = f"http://127.0.0.1:{port}"
    again = start(["serve", "--port", str(port)], env, tmp_path / "serve.log")
    try:
        wait_healthy(base, again, log=tmp_path / "serve.log")
        done = _wait_job(base, job_id, ("succeeded", "failed", "cancelled"), timeout=90)
        assert done["status"] == "succeeded" and done["attempts"] == 2, done
    finally:
        stop(again)
