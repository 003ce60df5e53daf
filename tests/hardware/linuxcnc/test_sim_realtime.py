"""The simulator's HAL threads at a real-time priority (hardware/linuxcnc/sim_realtime.py)."""

from __future__ import annotations

import os
from pathlib import Path

from hardware.linuxcnc.sim_realtime import SERVO_PRIORITY, hal_thread_ids


def _task(root: Path, pid: int, tid: int, comm: str) -> None:
    (root / str(pid) / "task" / str(tid)).mkdir(parents=True)
    (root / str(pid) / "task" / str(tid) / "comm").write_text(comm + "\n")


def test_hal_threads_are_the_rtapi_app_threads_named_for_hal(tmp_path):
    for pid, comm in ((10, "rtapi_app"), (20, "python3"), (30, "rtapi_app")):
        (tmp_path / str(pid)).mkdir()
        (tmp_path / str(pid) / "comm").write_text(comm + "\n")
    _task(tmp_path, 10, 10, "rtapi_app")
    _task(tmp_path, 10, 11, "rtapi_app:mesg")
    _task(tmp_path, 10, 12, "rtapi_app:T#0")
    _task(tmp_path, 20, 21, "rtapi_app:T#0")   # not an rtapi_app process (a name is no proof)
    _task(tmp_path, 30, 31, "rtapi_app:T#1")
    (tmp_path / "self").mkdir()
    assert sorted(hal_thread_ids(tmp_path)) == [12, 31]


def test_the_simulators_servo_thread_runs_real_time_where_the_host_permits(lcnc_xyz):
    tids = hal_thread_ids(ipc_namespace=lcnc_xyz.ipc_namespace)  # its own (None: every one on the host)
    assert tids, "the running simulator has no HAL thread"
    if os.geteuid() != 0:  # an unprivileged host: ordinary scheduling, and the simulator says why
        assert lcnc_xyz.realtime_threads >= len(tids) or lcnc_xyz.realtime_note
        return
    # at least its own (a simulator sharing the host's namespaces finds every one's threads)
    assert lcnc_xyz.realtime_threads >= len(tids), lcnc_xyz.realtime_note
    for tid in tids:
        assert os.sched_getscheduler(tid) == os.SCHED_FIFO
        assert os.sched_getparam(tid).sched_priority == SERVO_PRIORITY
    sensor = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and "sensor_hal.py" in _cmdline(p)]
    assert sensor and all(os.sched_getscheduler(pid) == os.SCHED_FIFO for pid in sensor)


def _cmdline(proc: Path) -> str:
    try:
        return (proc / "cmdline").read_bytes().decode(errors="replace")
    except OSError:  # the process ended meanwhile
        return ""
