"""Bench: the closed loop on a whole board through the API: per-trace child jobs
against the board mode (one reconstruct and one compensate job per batch of traces).

Run: .venv/bin/python -m pytest tests/bench/test_bench_board_loop.py -s -o addopts="" -q

S1 part (60 x 40 mm, nominal mesh on a 0.5 mm grid), boards of 9 / 81 / 300 traces
(:func:`app.reference.boards.board_traces`: the seed's nine; then lines, arcs and free
curves in turn), a mock machine holding the as-made part (seed 11, +-0.15 mm, dz 0.03 mm,
1 um probe noise), ``closed_loop`` with ``joint_probing`` (field planner), no print.  The
same board runs twice in one service, ``board_jobs: false`` (2 child jobs per trace, as
before) and ``true``; measured: the loop's wall time from submission to success (TestClient,
compute jobs in their own processes as in service), the number of child jobs, and the
reconstruct + compensate share.  Both loops give the same programs (same commands per
trace): the board mode changes the bookkeeping, not the result.
"""

from __future__ import annotations

import math
import os
import time

import pytest

from app.reference.boards import board_traces, s1_part
from app.reference.s1 import as_made, s1_mesh
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")
PROCESS = {"deviation_amplitude_mm": 0.15, "deviation_wavelength_mm": 15.0}
SIZES = tuple(int(n) for n in os.environ.get("BOARD_LOOP_SIZES", "9,81,300").split(","))
# the per-trace loop takes ~10 s per trace on a loaded 2-core machine: set this lower to skip it on large boards
BEFORE_MAX = int(os.environ.get("BOARD_LOOP_BEFORE_MAX", "300"))


def _setup(client, n: int) -> dict:
    nominal = s1_mesh(grid_mm=0.5).export(file_type="stl")
    true_stl = as_made(seed=11, amplitude_mm=0.15).mesh(grid_mm=0.5).export(file_type="stl")
    part = client.post("/api/v1/parts", files={"file": ("s1.stl", nominal)}, headers=OP).json()
    real = client.post("/api/v1/parts", files={"file": ("real.stl", true_stl)}, headers=OP).json()
    body = [{"name": f"t{i}", "geometry": g, "frame": "xy", "standoff_mm": 0.1}
            for i, g in enumerate(board_traces(s1_part(), n))]
    response = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=body, headers=OP)
    assert response.status_code in (200, 201), response.text
    machine = client.post("/api/v1/machines", json={
        "name": "sim", "port": "mock://", "dialect": "marlin",
        "mock": {"true_part_id": real["id"], "placement": {"dz": 0.03}, "probe_noise_mm": 0.001}},
        headers=OP).json()
    return {"part_id": part["id"], "trace_ids": [t["id"] for t in response.json()["items"]],
            "machine_id": machine["id"]}


def _loop(client, setup: dict, board: bool) -> tuple[float, dict]:
    t0 = time.perf_counter()
    response = client.post("/api/v1/jobs", json={"kind": "closed_loop", "params": {
        **setup, "joint_probing": True, "probe": PROCESS, "sigma_mm": 0.001, "board_jobs": board}}, headers=OP)
    assert response.status_code == 202, response.text
    done = wait_for(client, response.json()["id"], timeout=3600)
    wall = time.perf_counter() - t0
    assert done["status"] == "succeeded", done["error"]
    return wall, done


def _programs(client, done: dict) -> list[str]:
    return [client.get(f"/api/v1/jobs/{e['compensate']}/artifacts/{e.get('print_artifact', 'print.gcode')}",
                       headers=OP).text for e in done["result"]["traces"]]


@pytest.mark.timeout(7200)
def test_closed_loop_board_mode_against_per_trace_jobs(client):
    rows = []
    for n in SIZES:
        setup = _setup(client, n)
        before = _loop(client, setup, board=False)[0] if n <= BEFORE_MAX else math.nan
        after, new = _loop(client, setup, board=True)
        assert new["message"] == f"{n}/{n} traces done"
        assert len(_programs(client, new)) == n  # every trace's program readable as the result names it
        children = ({e["reconstruct"] for e in new["result"]["traces"]}
                    | {e["compensate"] for e in new["result"]["traces"]})
        rows.append((n, before, after, 2 * n, len(children)))
    print("\n\nclosed_loop on S1 boards (joint_probing, field planner, mock machine, no print), wall s from submission")
    print(f"{'traces':>6} {'per-trace jobs s':>16} {'board mode s':>12} {'ratio':>6} {'rec+comp jobs before':>20} "
          f"{'after':>6}")
    for n, before, after, jobs_before, jobs_after in rows:
        print(f"{n:>6} {before:>16.1f} {after:>12.1f} {after / before:>6.2f} {jobs_before:>20} {jobs_after:>6}"
              + ("  (per-trace loop not run: BOARD_LOOP_BEFORE_MAX)" if math.isnan(before) else ""))
    for n, before, after, _, _ in rows:
        if n >= 81 and n <= BEFORE_MAX:
            assert after < 0.5 * before, (n, before, after)
