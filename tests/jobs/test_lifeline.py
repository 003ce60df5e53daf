"""A compute process dies with the server it serves (``bind_to``), even a SIGKILLed one."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).parents[2]


def test_a_bound_process_dies_at_once_when_its_server_is_killed():
    server = subprocess.Popen(["sleep", "120"])
    code = (f"import time\nfrom app.runtime.compute_child import bind_to\nbind_to({server.pid})\n"
            "print('bound', flush=True)\ntime.sleep(120)\n")
    child = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "bound"
        time.sleep(0.3)
        assert child.poll() is None  # alive while its server lives
        server.kill()
        server.wait()
        killed_at = time.monotonic()
        assert child.wait(timeout=10) == -signal.SIGKILL
        assert time.monotonic() - killed_at < 2.0
    finally:
        for process in (server, child):
            if process.poll() is None:
                process.kill()
                process.wait()


def test_a_process_bound_to_a_server_already_gone_dies_at_once():
    """A compute process whose server died while it was being started (before it bound
    itself) does not outlive it."""
    server = subprocess.Popen(["true"])
    server.wait()   # reaped: its pid names no process
    code = (f"import time\nfrom app.runtime.compute_child import bind_to\nbind_to({server.pid})\n"
            "print('bound', flush=True)\ntime.sleep(120)\n")
    child = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert child.wait(timeout=30) == -signal.SIGKILL
        assert child.stdout is not None and child.stdout.read() == ""
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
