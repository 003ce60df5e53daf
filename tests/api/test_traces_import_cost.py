"""``traces:import`` of a 1000-trace board costs the server seconds, not tens of seconds:
process CPU time (robust to a loaded machine, unlike wall time) of one import of the
150 x 100 mm dome's 1000-trace board (lines, arcs and free curves), the part's mesh
already loaded by an earlier trace.  The goal is CPU_LIMIT_S; a host too slow for it (where
the core's draping of the same board alone takes most of it) holds the import to OVER_CORE
times that draping, measured in the same process."""

from __future__ import annotations

import time
from typing import Any

from app.geometry.traces import build_nominal_traces
from app.reference.boards import BoardPart, board_traces, dome_part
from tests.conftest import auth

OP = auth("operator")
TRACES = 1000
CPU_LIMIT_S = 2.0  # the goal; measured 0.73-1.00 s on a 2-core box at load average 21-27
# the import over the core's draping (app.geometry.traces.build_nominal_traces) of the same
# board: 1.5-2.0 on a host where that draping alone takes 1.4-1.9 s of CPU
OVER_CORE = 2.5


def _core_cpu(dome: BoardPart, geometries: list[dict[str, Any]]) -> float:
    """Process CPU s of the core's draping of ``geometries`` over the dome's mesh, best of two."""
    mesh, best = dome.mesh(grid_mm=0.5), float("inf")
    for _ in range(2):
        started = time.process_time()
        assert build_nominal_traces(mesh, geometries) is not None
        best = min(best, time.process_time() - started)
    return best


def test_importing_a_1000_trace_board_costs_seconds_of_cpu(client):
    dome = dome_part()
    part = client.post("/api/v1/parts", files={"file": ("dome.stl", dome.mesh(grid_mm=0.5).export(file_type="stl"))},
                       headers=OP).json()
    geometries = board_traces(dome, TRACES)
    body = [{"name": f"t{i}", "geometry": g, "frame": "xy", "standoff_mm": 0.1} for i, g in enumerate(geometries)]
    first = client.post(f"/api/v1/parts/{part['id']}/traces", json=body[0], headers=OP)  # loads the mesh
    assert first.status_code == 201, first.text
    cpu = time.process_time()
    response = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=body, headers=OP)
    cpu = time.process_time() - cpu
    assert response.status_code == 201, response.text
    items = response.json()["items"]
    assert [t["name"] for t in items] == [f"t{i}" for i in range(TRACES)]
    # each trace lies on the dome: its nominal points at the part's analytic height (the mesh's
    # 0.5 mm facets are within 0.05 mm of it)
    for t in items[::97]:
        points = t["nominal"]["points"]
        assert len(points) >= 2
        assert max(abs(z - h) for (_, _, z), h in zip(points, dome.height([p[:2] for p in points]))) < 0.05
    assert client.get(f"/api/v1/parts/{part['id']}/traces", params={"limit": 1},
                      headers=OP).json()["total"] == TRACES + 1
    if cpu > CPU_LIMIT_S:
        core = _core_cpu(dome, geometries)
        assert cpu <= OVER_CORE * core, (f"traces:import of {TRACES} traces took {cpu:.2f} s of CPU, "
                                         f"{cpu / core:.2f} x the core's draping ({core:.2f} s)")
