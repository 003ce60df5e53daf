"""Which process ran a job's attempt, told apart from a later process that reuses its pid.

A pid alone names a process only while it lives: the kernel hands it out again.  What names
one process for good is its pid, its start time (clock ticks after boot, field 22 of
``/proc/<pid>/stat``) and the boot it started in (``/proc/sys/kernel/random/boot_id``): a
:data:`ProcessRecord` ``{"pid": int, "start_ticks": int, "boot_id": str}``, stored with the
job (``jobs.process``) when its compute process is chosen.

Before a job whose earlier attempt ran in a process that may still live (its server was
SIGKILLed and restarted) runs again, :func:`make_gone` waits for that process to end (it is
bound to its server's life and normally ends within 0.1 s) and kills it when it does not:
two attempts of one job never compute at the same time.  Linux only: elsewhere a record is
never made and nothing is checked.
"""

from __future__ import annotations

import os
import signal
import time
from typing import Any

ProcessRecord = dict[str, Any]
POLL_S = 0.02


def start_ticks(pid: int) -> int | None:
    """The start time (clock ticks since boot) of the live, non-zombie process ``pid``; None
    when there is none (or no /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return None if fields[0] in ("Z", "X") else int(fields[19])


def boot_id() -> str | None:
    """This boot's id (a UUID the kernel draws at boot); None without /proc."""
    try:
        with open("/proc/sys/kernel/random/boot_id") as f:
            return f.read().strip()
    except OSError:
        return None


def identify(pid: int | None) -> ProcessRecord | None:
    """The record naming the live process ``pid`` (see the module); None when it cannot be made."""
    if pid is None:
        return None
    ticks, boot = start_ticks(pid), boot_id()
    if ticks is None or boot is None:
        return None
    return {"pid": int(pid), "start_ticks": ticks, "boot_id": boot}


def alive(record: ProcessRecord | None) -> bool:
    """Whether the process ``record`` names still runs on this host: same boot, same pid, same
    start time (a zombie has ended).  A record of another boot (or another host) is not."""
    if not isinstance(record, dict):
        return False
    try:
        pid, ticks, boot = int(record["pid"]), int(record["start_ticks"]), str(record["boot_id"])
    except (KeyError, TypeError, ValueError):
        return False
    return boot == boot_id() and start_ticks(pid) == ticks


def _wait_gone(record: ProcessRecord, wait_s: float) -> bool:
    deadline = time.monotonic() + wait_s
    while alive(record):
        if time.monotonic() >= deadline:
            return False
        time.sleep(POLL_S)
    return True


def make_gone(record: ProcessRecord | None, wait_s: float = 1.0, kill_wait_s: float = 5.0) -> str:
    """End the process ``record`` names before its job runs again.

    Returns "gone" (it was not running), "exited" (it ended by itself within ``wait_s``),
    "killed" (SIGKILLed, ended within ``kill_wait_s``) or "alive" (it survived: not ours to
    kill, or stuck in the kernel)."""
    if not alive(record):
        return "gone"
    assert record is not None
    if _wait_gone(record, wait_s):
        return "exited"
    try:
        os.kill(int(record["pid"]), signal.SIGKILL)
    except ProcessLookupError:
        return "exited"
    except PermissionError:
        return "alive"
    return "killed" if _wait_gone(record, kill_wait_s) else "alive"
