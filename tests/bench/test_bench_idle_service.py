"""An idle service's CPU: ``conforma serve`` on a fresh data directory, left alone.

Run: .venv/bin/python -m pytest tests/bench/test_bench_idle_service.py -s -o addopts="" -q

The server starts at its defaults (embedded queue consumers, the reaper, the compute fork
server and processes warmed up, no viewer), is left to finish starting (until two 3 s windows
in a row cost its tree less than ``SETTLED_CPU_S`` each: the compute processes' imports are over), then the
CPU seconds (user + system, from ``/proc/<pid>/stat``) of its whole process tree are sampled
over ``CONFORMA_BENCH_IDLE_S`` (30 s by default) and printed per minute of wall time.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.helpers.cputime import tree_cpu_and_peak
from tests.helpers.processes import free_port

IDLE_S = float(os.environ.get("CONFORMA_BENCH_IDLE_S", "30"))
SETTLED_CPU_S = 0.15  # started: the tree used less than this in each of two 3 s windows (imports: seconds)
GOAL_CPU_PER_MIN_S = 0.6  # an idle service wakes about once a second: ~no CPU


@pytest.mark.timeout(IDLE_S + 300)
def test_bench_an_idle_service_uses_almost_no_cpu(tmp_path):
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("CONFORMA_")}
    server = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--data-dir", str(tmp_path / "data"),
                               "--port", str(port), "--no-viewer"], env=env, cwd=Path(__file__).parents[2],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            assert server.poll() is None, server.stderr.read() if server.stderr else "the server exited"
            try:
                if httpx.get(f"{base}/api/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() < deadline, "the server did not answer /health in 120 s"
            time.sleep(0.2)
        quiet = 0
        while quiet < 2:  # the compute processes' warm-up: seconds of imports, in stages
            settle0 = tree_cpu_and_peak(server.pid)[0]
            time.sleep(3.0)
            quiet = quiet + 1 if tree_cpu_and_peak(server.pid)[0] - settle0 < SETTLED_CPU_S else 0
            assert time.monotonic() < deadline + 120, "the server did not settle in 240 s"
        cpu0, wall0 = tree_cpu_and_peak(server.pid)[0], time.monotonic()
        time.sleep(IDLE_S)
        cpu, wall = tree_cpu_and_peak(server.pid)[0] - cpu0, time.monotonic() - wall0
        per_min = cpu / wall * 60
        print(f"\nidle service tree: {cpu:.2f} s CPU in {wall:.1f} s wall = {per_min:.2f} s CPU per minute")
        assert per_min < GOAL_CPU_PER_MIN_S
    finally:
        server.terminate()
        try:
            server.wait(30)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
