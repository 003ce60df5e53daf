"""Simulators side by side, each in namespaces of its own (hardware/linuxcnc/sim_namespace.py):
one's HAL, controller state and shutdown never reach the other, and HAL commands reach the
simulator they name (hardware/linuxcnc/hal_command.py)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from hardware.linuxcnc import SimBlock, SimController
from hardware.linuxcnc.hal_command import HAL_PREFIX_VAR, hal_command
from hardware.linuxcnc.sim_namespace import isolation_available, write_nml
from hardware.linuxcnc.sim_realtime import hal_thread_ids
from tests.helpers.real_components import missing


def test_a_hal_command_runs_through_the_prefix_its_environment_names():
    env = {HAL_PREFIX_VAR: "docker exec 'the controller'"}
    assert hal_command(["halcmd", "show"], env) == ["docker", "exec", "the controller", "halcmd", "show"]
    assert hal_command(["halcmd", "show"], {}) == ["halcmd", "show"]


def test_the_nml_file_serves_on_the_runs_port(tmp_path):
    from hardware.linuxcnc.sim_namespace import SYSTEM_NML

    if not SYSTEM_NML.exists():
        missing("LinuxCNC", f"{SYSTEM_NML} not installed")
    write_nml(tmp_path / "run.nml", 40123)
    system, ours = SYSTEM_NML.read_text(), (tmp_path / "run.nml").read_text()
    assert "TCP=5005" in system and "TCP=5005" not in ours
    assert ours.count("TCP=40123") == system.count("TCP=5005")
    assert ours.replace("TCP=40123", "TCP=5005") == system


def test_hal_threads_of_one_namespace(tmp_path):
    for pid, namespace in ((10, "ipc:[1]"), (30, "ipc:[2]")):
        (tmp_path / str(pid) / "ns").mkdir(parents=True)
        (tmp_path / str(pid) / "comm").write_text("rtapi_app\n")
        (tmp_path / str(pid) / "ns" / "ipc").symlink_to(namespace)
        (tmp_path / str(pid) / "task" / str(pid + 1)).mkdir(parents=True)
        (tmp_path / str(pid) / "task" / str(pid + 1) / "comm").write_text("rtapi_app:T#0\n")
    assert sorted(hal_thread_ids(tmp_path)) == [11, 31]
    assert hal_thread_ids(tmp_path, ipc_namespace="ipc:[2]") == [31]


def _tool_maps(sim: SimController) -> set[str]:
    """The tool table files ``sim``'s task processes map (``.tool.mmap``, from /proc/<pid>/maps)."""
    found = set()
    for pid in sim.task_pids():
        for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
            if line.endswith(".tool.mmap"):
                found.add(line.split(maxsplit=5)[-1])
    return found


def test_two_simulators_run_side_by_side_and_neither_reaches_the_other(lcnc_xyz):
    if not isolation_available():
        missing("simulator namespaces", "creating namespaces needs root and util-linux's unshare / nsenter")
    first = lcnc_xyz.snapshot()
    task = lcnc_xyz.task_pids()
    assert len(task) == 1
    with SimController("xyz") as second:
        assert second.ipc_namespace is not None and second.ipc_namespace != lcnc_xyz.ipc_namespace
        assert second.ipc_namespace != os.readlink("/proc/self/ns/ipc")
        second.set_surface(SimBlock.plane(-7.5, 0.0))
        assert second.snapshot()["conforma-surface.offset"] == pytest.approx(-7.5)
        session = second.session(enable=True)
        try:
            session.set("estop", "off")
            deadline = time.monotonic() + 5.0   # the controller's status lags the ACK (a loaded host's by more)
            while session.get("estop") != "OFF" and time.monotonic() < deadline:
                time.sleep(0.02)
            assert session.get("estop") == "OFF"
        finally:
            session.close()
        assert lcnc_xyz.snapshot() == first  # not its surface, not its e-stop
        # each task maps a tool table of its own: a shared one is resized under the other's task
        # when a simulator starts or stops, and that task dies of SIGBUS at its next tool read
        ours, theirs = _tool_maps(lcnc_xyz), _tool_maps(second)
        assert len(ours) == len(theirs) == 1 and ours != theirs, (ours, theirs)
        assert next(iter(ours)).startswith(str(lcnc_xyz.workdir)), ours
        assert set(hal_thread_ids(ipc_namespace=second.ipc_namespace)).isdisjoint(
            hal_thread_ids(ipc_namespace=lcnc_xyz.ipc_namespace))
    assert lcnc_xyz.running and lcnc_xyz.snapshot() == first  # the other's shutdown ended only its own
    # the other's start and stop left this one's task running
    time.sleep(1.0)  # several task cycles, each reading the tool table
    assert lcnc_xyz.task_pids() == task
    session = lcnc_xyz.session(enable=True)
    try:  # a command the task must receive is answered
        session.set("estop", "on")
    finally:
        session.close()


def test_a_host_that_refuses_namespaces_runs_simulators_in_its_own(monkeypatch):
    """Root without CAP_SYS_ADMIN (a plain container): ``unshare`` fails, so simulators keep
    the file lock instead of failing to start."""
    import subprocess

    from hardware.linuxcnc import sim_namespace

    monkeypatch.setattr(sim_namespace.os, "geteuid", lambda: 0)
    monkeypatch.setattr(sim_namespace.shutil, "which", lambda name: f"/usr/bin/{name}")
    refused = b"unshare: unshare failed: Operation not permitted"
    monkeypatch.setattr(sim_namespace.subprocess, "run",
                        lambda args, **_: subprocess.CompletedProcess(args, 1, b"", refused))
    sim_namespace._namespaces_permitted.cache_clear()
    try:
        assert not sim_namespace.isolation_available()
    finally:
        sim_namespace._namespaces_permitted.cache_clear()
    monkeypatch.setenv("CONFORMA_SIM_SHARED_NAMESPACES", "1")
    assert not sim_namespace.isolation_available()
