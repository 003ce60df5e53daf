"""Bench: the resident memory of each process of the service over a board's closed loop.

Run: .venv/bin/python -m pytest tests/bench/test_bench_board_memory.py -s -o addopts="" -q

The board of :mod:`tests.bench.test_bench_board_api` (BOARD_API_TRACES traces, default 1000,
on the 150 x 100 mm dome; a mock machine holding the as-made part), the service warm as
deployed (``compute_warm_up``).  Each process of the service (this one: the server with the
TestClient; the fork server; the compute processes; multiprocessing's resource tracker) is
read from /proc: its resident memory (VmRSS) and proportional share (PSS: shared pages split
between the processes that map them) when the service is idle after the part, traces and
machine are set up; the largest total resident memory while the closed loop runs (sampled
every 0.25 s, with the PSS of the same sample) with each process's share of it and each one's
own peak, and the largest PSS total of those samples; and again after the loop.  With them the
loop's wall time and CPU: the server process's, the compute processes' jobs' (the part cache's
journal) and the live descendants' (a process that ended during the loop is not counted: a
lower bound), so that a change of the memory is seen beside what it costs.  The sum of
the resident memories counts a page shared by the fork server and its children once per
process; the PSS sum counts it once.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from app.reference.boards import board_traces, dome_part
from tests.bench.test_bench_board_api import PROCESS, TRACES, compute_cpu, cpu_now, true_part
from tests.conftest import auth
from tests.helpers.jobs import wait_for
from tests.helpers.processes import process_tree

OP = auth("operator")
MIB = 1024


def _role(pid: int, root: int) -> str:
    if pid == root:
        return "server"
    if "resource_tracker" in Path(f"/proc/{pid}/cmdline").read_text():
        return "tracker"
    parent = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    return "forkserver" if parent == root else "compute"


def _kb(path: str, key: str) -> int:
    return next(int(line.split()[1]) for line in Path(path).read_text().splitlines() if line.startswith(key + ":"))


def sample(pss: bool = False) -> dict[int, tuple[str, float, float]]:
    """pid -> (role, resident MiB, PSS MiB (0 unless ``pss``)) of the service's processes."""
    root, out = os.getpid(), {}
    for pid in process_tree(root):
        try:
            rss = _kb(f"/proc/{pid}/status", "VmRSS") / MIB
            share = _kb(f"/proc/{pid}/smaps_rollup", "Pss") / MIB if pss else 0.0
            out[pid] = (_role(pid, root), rss, share)
        except (OSError, StopIteration):
            continue
    return out


def line(label: str, processes: dict[int, tuple[str, float, float]]) -> str:
    each = ", ".join(f"{role} {rss:.0f}" for role, rss, _ in sorted(processes.values()))
    pss = sum(p for _, _, p in processes.values())
    return (f"{label:<26} total RSS {sum(r for _, r, _ in processes.values()):>6.0f} MiB"
            + (f", PSS {pss:>5.0f} MiB" if pss else "") + f"  ({each})")


@pytest.fixture
def settings(settings_factory):  # type: ignore[no-untyped-def]
    """Warm as deployed, at the default job lease."""
    return settings_factory(lease_s=30.0, compute_warm_up=True)


@pytest.mark.timeout(3600)
def test_board_loop_memory_per_process(client, settings):
    dome = dome_part()
    part = client.post("/api/v1/parts", files={"file": ("dome.stl", dome.mesh(grid_mm=0.5).export(file_type="stl"))},
                       headers=OP).json()
    truth = client.post("/api/v1/parts", files={
        "file": ("real.stl", true_part().mesh(grid_mm=0.5).export(file_type="stl"))}, headers=OP).json()
    body = [{"name": f"t{i}", "geometry": g, "frame": "xy", "standoff_mm": 0.1}
            for i, g in enumerate(board_traces(dome, TRACES))]
    imported = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=body, headers=OP)
    assert imported.status_code == 201, imported.text
    machine = client.post("/api/v1/machines", json={
        "name": "sim", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": truth["id"], "placement": {"dz": 0.03}, "probe_noise_mm": 0.001}},
        headers=OP).json()
    trace_ids = [t["id"] for t in imported.json()["items"]]
    del body, imported
    deadline = time.monotonic() + 300  # the warm-up: the fork server imports the compute core
    while not any(role == "compute" for role, _, _ in sample().values()) and time.monotonic() < deadline:
        time.sleep(0.5)
    time.sleep(12.0)  # the server's periodic heap trim (app.runtime.engine.HEAP_TRIM_S) has run
    idle = sample(pss=True)
    peak: dict[int, tuple[str, float, float]] = {}
    peak_pss = 0.0
    own: dict[int, tuple[str, float]] = {}
    stop = threading.Event()

    def watch() -> None:
        nonlocal peak, peak_pss
        while not stop.wait(0.25):
            now = sample(pss=True)
            peak_pss = max(peak_pss, sum(p for _, _, p in now.values()))
            for pid, (role, rss, _) in now.items():
                own[pid] = (role, max(rss, own.get(pid, (role, 0.0))[1]))
            if sum(r for _, r, _ in now.values()) > sum(r for _, r, _ in peak.values()):
                peak = now

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    (s0, d0), w0 = cpu_now(), time.perf_counter()
    submitted = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        "part_id": part["id"], "trace_ids": trace_ids, "machine_id": machine["id"], "joint_probing": True,
        "probe": PROCESS, "sigma_mm": 0.001, "board_jobs": True}}, headers=OP)
    assert submitted.status_code == 202, submitted.text
    done = wait_for(client, submitted.json()["id"], timeout=3600)
    accepted = done["status"] == "needs_attention"
    if accepted:  # as an operator would; the bench says so
        assert client.post(f"/api/v1/jobs/{done['id']}/accept", headers=OP).status_code == 202
        done = wait_for(client, done["id"], states=("succeeded", "failed", "cancelled"), timeout=3600)
    loop_wall, (s1, d1) = time.perf_counter() - w0, cpu_now()
    stop.set()
    watcher.join()
    assert done["status"] == "succeeded", done["error"]
    after = sample(pss=True)
    print(f"\n\n{TRACES}-trace dome board, closed loop through the API: resident memory per process (MiB)")
    print(line("idle, set up", idle))
    print(line("largest total in the loop", peak))
    print(f"largest PSS total in the loop {peak_pss:.0f} MiB")
    print("each process's own peak:   " + ", ".join(f"{role} {rss:.0f}" for role, rss in sorted(own.values())))
    print(f"the loop: wall {loop_wall:.1f} s; CPU server process {s1 - s0:.1f} s, compute jobs "
          f"{sum(compute_cpu(Path(settings.data_dir)).values()):.1f} s (journal), live descendants {d1 - d0:.1f} s")
    print(line("after the loop", after) + ("  (the loop needed attention: ACCEPTED by the bench)" if accepted else ""))
