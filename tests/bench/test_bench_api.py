"""API throughput/latency and job pickup latency against a real `conforma serve` process.

Targets: GET /api/v1/jobs/{id} with 64 concurrent clients on one process
>= 500 req/s with p99 < 50 ms; job submit -> start p50 < 50 ms.  The reference run in the
same process is GET /api/v1/health (no auth, no row to load), so the ratio shows what the
job read costs on top of the framework, whatever the machine's load.
"""

from __future__ import annotations

import statistics
import time
from datetime import datetime

import httpx
import numpy as np
import pytest

from tests.bench.loadgen import run_load
from tests.e2e.test_serve import env_for, free_port, start, stop, wait_healthy

KEY = "bench-operator-key"
CLIENTS = 64
DURATION_S = 6.0


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("bench") / "data"
    port = free_port()
    proc = start(["serve", "--port", str(port)],
                 env_for(data, CONFORMA_API_KEYS=f"{KEY}:operator", CONFORMA_LOG_LEVEL="warning"),
                 tmp_path_factory.mktemp("logs") / "serve.log")
    base = f"http://127.0.0.1:{port}"
    wait_healthy(base, proc)
    yield base
    stop(proc)


def test_job_read_throughput_and_latency(server):
    headers = {"Authorization": f"Bearer {KEY}"}
    job = httpx.post(f"{server}/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0, "artifact": True}},
                     headers=headers).json()
    time.sleep(0.5)
    url = f"{server}/api/v1/jobs/{job['id']}"
    rows = [
        ("/health, closed loop (reference)", run_load(f"{server}/api/v1/health", seconds=DURATION_S)),
        ("/jobs/{id}, closed loop", run_load(url, headers=headers, seconds=DURATION_S)),
        ("/jobs/{id}, offered 500 req/s", run_load(url, headers=headers, seconds=DURATION_S, rate=500)),
    ]
    print(f"\n{CLIENTS} concurrent keep-alive clients, {DURATION_S:.0f} s each, one server process:")
    print(f"  {'run':<36}{'req/s':>8}{'p50 ms':>9}{'p99 ms':>9}{'errors':>8}")
    for label, r in rows:
        print(f"  {label:<36}{r.rate:8.0f}{r.pct(50):9.1f}{r.pct(99):9.1f}{r.errors:8d}")
    ref, closed, offered = (r for _, r in rows)
    print(f"  job read / health throughput ratio: {closed.rate / ref.rate:.2f}")
    assert closed.errors == 0 and offered.errors == 0
    assert offered.rate >= 0.97 * 500, f"server could not sustain 500 req/s: {offered.rate:.0f}"
    assert offered.pct(99) < 50, f"p99 at 500 req/s: {offered.pct(99):.1f} ms"


def test_submit_to_start_latency(server):
    headers = {"Authorization": f"Bearer {KEY}"}
    pickups = []
    for _ in range(60):
        job = httpx.post(f"{server}/api/v1/jobs", json={"kind": "test_sleep", "params": {"seconds": 0}},
                         headers=headers).json()
        deadline = time.monotonic() + 10
        while (done := httpx.get(f"{server}/api/v1/jobs/{job['id']}", headers=headers).json())["started_at"] is None:
            assert time.monotonic() < deadline
            time.sleep(0.005)
        created = datetime.fromisoformat(done["created_at"])
        started = datetime.fromisoformat(done["started_at"])
        pickups.append((started - created).total_seconds() * 1000)
        time.sleep(0.05)  # let the worker go idle, as between real submissions
    p50, p95 = statistics.median(pickups), float(np.percentile(pickups, 95))
    print(f"\njob submit -> start (server timestamps), 60 jobs: p50 {p50:.1f} ms, p95 {p95:.1f} ms, max "
          f"{max(pickups):.1f} ms")
    assert p50 < 50
