"""Run a pytest selection again and again beside an artificial load, and count what failed.

``python -m tests.helpers.stress --runs 20 --load "--cpu 2 --cpu-load 60" -- -n 4 --dist loadgroup
tests/e2e/browser tests/hardware`` starts ``stress-ng`` with the ``--load`` arguments (in its own
process group, stopped at the end), then runs ``python -m pytest <args>`` ``--runs`` times, each
a fresh session (a new served instance, Chromium, LinuxCNC simulator: the starts and shutdowns
are where timing races hide).  Every run prints one line (exit code, wall time, load, the tests
that failed); the last line counts the failed runs and how often each test failed.  The exit
code is 0 only when every run passed.  ``make stress`` runs the browser and machine tests so.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter

FAILED = re.compile(r"^(?:FAILED|ERROR) (\S+)", re.MULTILINE)


def start_load(load: str) -> subprocess.Popen | None:
    """``stress-ng <load> --timeout 0`` in its own process group; None when ``load`` is empty."""
    if not load:
        return None
    if shutil.which("stress-ng") is None:
        raise SystemExit("stress: stress-ng is not installed (apt-get install -y stress-ng)")
    return subprocess.Popen(["stress-ng", *shlex.split(load), "--timeout", "0", "--quiet"],
                            stdout=subprocess.DEVNULL, start_new_session=True)


def stop_load(proc: subprocess.Popen | None) -> None:
    if proc is None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def run_once(pytest_args: list[str]) -> tuple[int, float, list[str]]:
    """One pytest session: its exit code, wall seconds and the failed node ids (``-rfE``)."""
    started = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-rfE", *pytest_args], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True)
    sys.stdout.write(proc.stdout)
    return proc.returncode, time.monotonic() - started, FAILED.findall(proc.stdout)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--load", default="--cpu 2 --cpu-load 60",
                        help="stress-ng's arguments ('' for no artificial load)")
    parser.add_argument("pytest_args", nargs=argparse.REMAINDER, help="after --: pytest's arguments")
    args = parser.parse_args(argv)
    pytest_args = [a for a in args.pytest_args if a != "--"] or ["tests/e2e/browser", "tests/hardware"]
    failures: Counter[str] = Counter()
    failed_runs = 0
    load = start_load(args.load)
    try:
        for run in range(1, args.runs + 1):
            code, wall, failed = run_once(pytest_args)
            failed_runs += code != 0
            failures.update(failed)
            print(f"stress run {run}/{args.runs}: exit {code}, {wall:.0f} s, load average "
                  f"{os.getloadavg()[0]:.1f}, failed: {', '.join(failed) or 'none'}", flush=True)
    finally:
        stop_load(load)
    flaky = ", ".join(f"{nodeid} ({count}x)" for nodeid, count in failures.most_common()) or "none"
    print(f"stress: {failed_runs} of {args.runs} runs failed (stress-ng {args.load or 'off'}); failed tests: {flaky}")
    return 1 if failed_runs else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
