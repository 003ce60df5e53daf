"""The real `conforma serve` and `conforma worker` processes over HTTP: first start,
a worker killed with SIGKILL mid-job, and a server restart that loses nothing."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import trimesh

from tests.helpers.processes import free_port, stop, wait_healthy

ROOT = Path(__file__).resolve().parents[2]
CONFORMA = [sys.executable, "-m", "app.cli"]
ADMIN = "e2e-admin-key-1"


def env_for(data_dir: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CONFORMA_")}
    env.update({"PYTHONPATH": str(ROOT), "CONFORMA_DATA_DIR": str(data_dir), "CONFORMA_VIEWER": "false",
                "CONFORMA_JOB_PLUGINS": "tests.jobs.sample_kinds", **extra})
    return env


def start(args: list[str], env: dict[str, str], log: Path | None = None) -> subprocess.Popen:
    out = open(log, "a") if log is not None else subprocess.PIPE  # noqa: SIM115 (closed with the process)
    return subprocess.Popen(CONFORMA + args, env=env, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)


def test_first_start_prints_url_and_a_working_operator_key(tmp_path):
    """A first ``conforma serve`` prints its URL and an operator key that works (it runs no
    compute job: its compute processes are not started)."""
    port = free_port()
    proc = start(["serve", "--port", str(port)], env_for(tmp_path / "data", CONFORMA_COMPUTE_WARM_UP="false"))
    try:
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any("Operator API key" in l for l in lines):
            lines.append(proc.stdout.readline())
        url_line = next(l for l in lines if "http://" in l)
        assert f"http://127.0.0.1:{port}/" in url_line
        key = next(l for l in lines if "Operator API key" in l).rsplit(" ", 1)[1].strip()
        base = f"http://127.0.0.1:{port}"
        wait_healthy(base, proc)
        headers = {"Authorization": f"Bearer {key}"}
        assert httpx.get(f"{base}/api/v1/parts", headers=headers).status_code == 200
        assert httpx.get(f"{base}/api/v1/keys", headers=headers).status_code == 403  # operator, not admin
    finally:
        stop(proc)


def test_sigkilled_worker_job_is_requeued_and_restart_keeps_everything(tmp_path):
    """A ``conforma worker`` SIGKILLed mid-job: a new worker runs the job to success on its
    second attempt, and a restarted server still serves the part, the job and its artifact
    byte for byte (compute processes started at the first job, not with each process)."""
    data = tmp_path / "data"
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    headers = {"Authorization": f"Bearer {ADMIN}"}
    # compute processes start at the job (tests/e2e/test_compute_dies_with_server.py runs warm)
    common = {"CONFORMA_API_KEYS": f"{ADMIN}:admin", "CONFORMA_LEASE_S": "1.5", "CONFORMA_REAPER_INTERVAL_S": "0.2",
              "CONFORMA_COMPUTE_WARM_UP": "false"}
    log = tmp_path / "processes.log"
    server = start(["serve", "--port", str(port)], env_for(data, CONFORMA_EMBEDDED_WORKER="false", **common), log)
    worker = start(["worker"], env_for(data, **common), log)
    try:
        wait_healthy(base, server)
        box = trimesh.creation.box([40, 60, 10]).export(file_type="stl")
        part = httpx.post(f"{base}/api/v1/parts", files={"file": ("box.stl", box)}, headers=headers).json()
        job = httpx.post(f"{base}/api/v1/jobs", json={"kind": "test_sleep",
                                                       "params": {"seconds": 3, "steps": 30, "artifact": True}},
                         headers=headers).json()
        deadline = time.monotonic() + 30
        while httpx.get(f"{base}/api/v1/jobs/{job['id']}", headers=headers).json()["progress"] < 0.2:
            assert time.monotonic() < deadline, f"job never started: {log.read_text()[-3000:]}"
            time.sleep(0.05)
        stop(worker, signal.SIGKILL)  # the whole process group, mid-job
        worker = start(["worker"], env_for(data, **common), log)
        deadline = time.monotonic() + 60
        while (done := httpx.get(f"{base}/api/v1/jobs/{job['id']}", headers=headers).json())["status"] != "succeeded":
            assert done["status"] in ("running", "queued"), done
            assert time.monotonic() < deadline, "requeued job did not finish"
            time.sleep(0.1)
        assert done["attempts"] == 2 and done["result"]["attempt"] == 2
        artifact = httpx.get(f"{base}{done['artifacts'][0]['url']}", headers=headers)
        assert artifact.status_code == 200
        stop(server)
        server = start(["serve", "--port", str(port)], env_for(data, **common), log)
        wait_healthy(base, server)
        assert httpx.get(f"{base}/api/v1/parts/{part['id']}", headers=headers).json()["sha256"] == part["sha256"]
        again = httpx.get(f"{base}/api/v1/jobs/{job['id']}", headers=headers).json()
        assert again["status"] == "succeeded" and again["artifacts"] == done["artifacts"]
        assert httpx.get(f"{base}{done['artifacts'][0]['url']}", headers=headers).content == artifact.content
    finally:
        stop(worker)
        stop(server)
