"""Wall time and CPU time of a command and of every process it starts, however deep.

``python -m tests.helpers.cputime python -m pytest -n 0 tests/some_test.py`` runs the command
as a child subreaper (``PR_SET_CHILD_SUBREAPER``), so that the fork server of the compute
pool, its compute processes and any ``conforma`` process a test starts are reaped here and
counted.  On a shared, loaded box a test's wall time says little; its CPU time (seconds,
user + system) is what it costs the suite's two workers.  Linux only.
"""

from __future__ import annotations

import ctypes
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

PR_SET_CHILD_SUBREAPER = 36
REAP_WAIT_S = 30.0  # how long orphans (a fork server) may take to exit after the command


def tree_cpu_and_peak(root: int) -> tuple[float, float]:
    """CPU seconds (user + system) of process ``root`` and every descendant alive now, and the
    largest resident peak (VmHWM, MiB) among the descendants (``root`` itself left out)."""
    children: dict[int, list[int]] = {}
    stats: dict[int, list[str]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            stats[int(entry)] = fields
            children.setdefault(int(fields[1]), []).append(int(entry))
    tick = os.sysconf("SC_CLK_TCK")
    cpu, peak, todo = 0.0, 0.0, [root]
    while todo:
        pid = todo.pop()
        if pid in stats:
            cpu += (int(stats[pid][11]) + int(stats[pid][12])) / tick
        if pid != root:
            try:
                hwm = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                           if line.startswith("VmHWM:"))
                peak = max(peak, int(hwm.split()[1]) / 1024)
            except (OSError, StopIteration):
                pass
        todo.extend(children.get(pid, []))
    return cpu, peak


def main(argv: list[str]) -> int:
    """Run ``argv``; print ``CPUTIME wall <s> s, cpu <s> s`` to stderr; its exit code."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    started = time.perf_counter()
    code = subprocess.call(argv)
    wall = time.perf_counter() - started
    deadline = time.monotonic() + REAP_WAIT_S
    while time.monotonic() < deadline:
        try:
            if os.waitpid(-1, os.WNOHANG)[0] == 0:
                time.sleep(0.2)
        except ChildProcessError:
            break
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(f"CPUTIME wall {wall:.1f} s, cpu {usage.ru_utime + usage.ru_stime:.1f} s "
          f"(user {usage.ru_utime:.1f}, sys {usage.ru_stime:.1f}), exit {code}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
