"""Bench: a 5,000-track board with its 1,100 pads (generated: 100 nets of 50 tracks, a pad
every fifth joint) end to end through the API on a curved 180 x 120 mm part: the committed
import (goal <= 30 s), the circuit program's netlist checks at submission (short and open,
over all of it) and a field probe plan over its traces and pad rings.

Run: .venv/bin/python -m pytest tests/bench/test_bench_board_scale.py -s -o addopts="" -q
"""

from __future__ import annotations

import os
import time

from tests.api.test_circuit_scale import cpu_s, import_board
from tests.circuits.boards import RowBoard
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


def test_a_5000_track_board_imports_checks_and_plans(client):
    board = RowBoard(rows=100, per_row=50)
    body, wall, cpu = import_board(client, board, limit=50)
    assert body["totals"]["traces"] == board.tracks == 5000 and body["totals"]["pads"] == board.pads == 1100
    record = client.get(f"/api/v1/circuit-imports/{body['import_id']}", headers=OP).json()
    t0, c0 = time.perf_counter(), cpu_s()
    plan = client.post("/api/v1/jobs", headers=OP, json={"kind": "probe_plan", "params": {
        "trace_ids": record["trace_ids"] + record["probe_trace_ids"]}})
    assert plan.status_code == 202, plan.text
    checked = client.post("/api/v1/jobs", headers=OP, json={"kind": "circuit_program", "params": {
        "import_id": body["import_id"], "closed_loop_job_id": plan.json()["id"]}})
    check_wall, check_cpu = time.perf_counter() - t0, cpu_s() - c0
    assert checked.status_code == 422 and "closed_loop" in checked.text, checked.text   # the net checks passed
    t1, c1 = time.perf_counter(), cpu_s()
    planned = wait_for(client, plan.json()["id"], timeout=1800)
    plan_wall, plan_cpu = time.perf_counter() - t1, cpu_s() - c1
    assert planned["status"] == "succeeded", planned["error"]
    print(f"\n5,000 tracks + 1,100 pads (load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores):\n"
          f"  import (read, map, drape 6,100 traces and rings, commit): {wall:.1f} s wall, {cpu:.1f} s CPU\n"
          f"  circuit_program submission (plan submitted, short + open checks): {check_wall:.1f} s wall, "
          f"{check_cpu:.1f} s CPU\n"
          f"  field probe plan over {len(record['trace_ids']) + len(record['probe_trace_ids'])} traces: "
          f"{plan_wall:.1f} s wall, {plan_cpu:.1f} s CPU, {planned['result'].get('count', '?')} stations")
    assert wall <= 30 or cpu <= 30, (wall, cpu)
