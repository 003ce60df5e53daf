"""``traces:import`` of the dome's 1000-trace board, and the core's share of it.

Run: .venv/bin/python -m pytest tests/bench/test_bench_traces_import.py -s -o addopts="" -q -n 0

The 150 x 100 mm dome (:func:`app.reference.boards.dome_part`, 0.5 mm grid) and its
1000-trace board (:func:`app.reference.boards.board_traces`) through the API (TestClient, the
part's mesh loaded by an earlier trace): process CPU s and wall s of three imports; then the
core alone on the same board and mesh, :func:`app.geometry.traces.build_nominal_traces`
(curves, CL points, draping), in thread CPU s.  The difference is what the service adds
(validation, slope checks, the stored JSON, the insert, the response).
"""

from __future__ import annotations

import io
import os
import time

import trimesh

from app.geometry.tolerance import Tolerance
from app.geometry.traces import build_nominal_traces
from app.reference.boards import board_traces, dome_part
from tests.conftest import auth

OP = auth("operator")
TRACES = 1000


def test_traces_import_beside_the_core(client):
    dome = dome_part()
    stl = dome.mesh(grid_mm=0.5).export(file_type="stl")
    part = client.post("/api/v1/parts", files={"file": ("dome.stl", stl)}, headers=OP).json()
    geometries = board_traces(dome, TRACES)
    body = [{"name": f"t{i}", "geometry": g, "frame": "xy", "standoff_mm": 0.1} for i, g in enumerate(geometries)]
    assert client.post(f"/api/v1/parts/{part['id']}/traces", json=body[0], headers=OP).status_code == 201
    runs = []
    for _ in range(3):
        c0, w0 = time.process_time(), time.perf_counter()
        response = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=body, headers=OP)
        runs.append((time.process_time() - c0, time.perf_counter() - w0))
        assert response.status_code == 201, response.text
    mesh = trimesh.load(io.BytesIO(stl), file_type="stl")
    c0 = time.thread_time()
    draped = build_nominal_traces(mesh, geometries, Tolerance())
    core = time.thread_time() - c0
    assert draped is not None and len(draped) == TRACES
    print(f"\ntraces:import of {TRACES} traces: " + ", ".join(f"{c:.2f} s CPU / {w:.2f} s wall" for c, w in runs)
          + f" (response {len(response.content) / 2**20:.1f} MiB); the core alone (build_nominal_traces) "
          f"{core:.2f} s CPU; load average {os.getloadavg()[0]:.1f}")
