"""The simulator's HAL threads at a real-time priority, as on a machine's controller.

LinuxCNC's uspace build runs its HAL threads (the servo thread: motion planning, the joints,
the sampler) with ordinary scheduling when the kernel is not a real-time one, as on a CI
host: there a busy host delays whole servo periods, and the simulated machine's motion and
sensor timing then follow the host's load instead of the controller's period.  A machine's
controller runs them SCHED_FIFO.  :func:`servo_threads_realtime` gives the simulator's HAL
threads SCHED_FIFO priority ``SERVO_PRIORITY`` (above the simulated sensor, which runs at 1:
``sensor_hal.py``) where the host permits it (root or CAP_SYS_NICE); elsewhere it changes
nothing and says so.  Linux only (``/proc``).
"""

from __future__ import annotations

import os
from pathlib import Path

SERVO_PRIORITY = 10
HAL_THREAD_PREFIX = "rtapi_app:T#"  # uspace names each HAL thread so (the servo thread is T#0)


def _comm(path: Path) -> str:
    try:
        return (path / "comm").read_text().strip()
    except OSError:
        return ""


def ipc_namespace_of(pid: Path) -> str | None:
    """The ``ns/ipc`` link of the process directory ``pid`` (``ipc:[<inode>]``), None when gone."""
    try:
        return os.readlink(pid / "ns" / "ipc")
    except OSError:
        return None


def hal_thread_ids(proc: Path = Path("/proc"), ipc_namespace: str | None = None) -> list[int]:
    """The thread ids of every ``rtapi_app`` HAL thread visible in ``proc``; with
    ``ipc_namespace`` (a ``/proc/<pid>/ns/ipc`` link, ``ipc:[<inode>]``) only those of the
    simulator in that namespace (a host shows every namespace's simulator)."""
    tids = []
    for pid in proc.iterdir():
        if not pid.name.isdigit() or _comm(pid) != "rtapi_app":
            continue
        if ipc_namespace is not None and ipc_namespace_of(pid) != ipc_namespace:
            continue
        try:
            tasks = list((pid / "task").iterdir())
        except OSError:
            continue
        tids += [int(t.name) for t in tasks if _comm(t).startswith(HAL_THREAD_PREFIX)]
    return tids


def servo_threads_realtime(priority: int = SERVO_PRIORITY, ipc_namespace: str | None = None) -> tuple[int, str | None]:
    """(how many HAL threads now run SCHED_FIFO at ``priority``, why none did or None); with
    ``ipc_namespace`` only the simulator's in that namespace (:func:`hal_thread_ids`)."""
    tids = hal_thread_ids(ipc_namespace=ipc_namespace)
    if not tids:
        return 0, "no rtapi_app HAL thread found"
    done = 0
    reason = None
    for tid in tids:
        try:
            if os.sched_getscheduler(tid) != os.SCHED_OTHER:
                done += 1  # already real-time (a real-time kernel: uspace set it itself)
                continue
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            done += 1
        except OSError as exc:
            reason = f"thread {tid}: {exc.strerror}"
    return done, reason
