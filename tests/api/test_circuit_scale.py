"""A 500-track board with its 110 pads (generated, every count known) through the API: the
import commits within its time bound, its answer pages (limit / offset, with totals), the
netlist checks of a circuit program pass over all of it (one connected piece per net, no
shorts), and a field probe plan covers its traces and pad rings.  The 5,000-track figure is
in tests/bench/test_bench_board_scale.py."""

from __future__ import annotations

import resource
import time

import numpy as np
import pytest

from app.reference.s1 import s1_mesh
from tests.circuits.boards import RowBoard
from tests.conftest import auth
from tests.helpers.jobs import wait_for

OP = auth("operator")


def big_part_stl() -> bytes:
    """S1 stretched 3 x in x and y: a 180 x 120 mm curved top (boards up to 150 x 115 mm)."""
    mesh = s1_mesh(grid_mm=1.0)
    mesh.apply_transform(np.diag([3.0, 3.0, 1.0, 1.0]))
    return mesh.export(file_type="stl")


def cpu_s() -> float:
    """CPU seconds of this process and its finished children (the import's child process)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def import_board(client, board: RowBoard, **query) -> tuple[dict, float, float]:
    """Upload the part, import the board (committed); the answer, wall s and CPU s of the import."""
    part = client.post("/api/v1/parts", files={"file": ("big.stl", big_part_stl())}, headers=OP).json()
    t0, c0 = time.perf_counter(), cpu_s()
    done = client.post(f"/api/v1/parts/{part['id']}/circuits:import", headers=OP, params=query,
                       files=[("files", ("rows.kicad_pcb", board.kicad().encode()))], data={"options": "{}"})
    wall, cpu = time.perf_counter() - t0, cpu_s() - c0
    assert done.status_code == 201, done.text
    return done.json(), wall, cpu


def test_a_500_track_board_imports_pages_and_passes_the_net_checks(client):
    board = RowBoard(rows=10, per_row=50)
    body, wall, cpu = import_board(client, board, limit=100)
    assert body["totals"]["traces"] == board.tracks == 500 and body["totals"]["pads"] == board.pads == 110
    assert len(body["traces"]) == 100 and len(body["pads"]) == 100 and body["totals"]["warnings"] == 0
    assert len(body["probe_trace_ids"]) == board.pads                       # every pad's ring, unpaged
    assert wall <= 30 or cpu <= 6, (wall, cpu)           # ~1.5 s CPU: generous for a loaded 2-core box
    record = client.get(f"/api/v1/circuit-imports/{body['import_id']}", headers=OP).json()
    assert len(record["trace_ids"]) == 500 and len(record["pads"]) == 110
    assert len(record["files"][0]["connections"]) == board.rows              # one piece per net
    # a page of no rows is a 422 naming limit
    empty = client.post("/api/v1/parts/x/circuits:import", headers=OP, params={"limit": 0})
    assert empty.status_code == 422 and "limit" in empty.text
    # the circuit program's submission checks (no short, no open over 500 tracks and 110 pads) pass:
    # what refuses it is the loop check that follows them
    plan = client.post("/api/v1/jobs", headers=OP, json={"kind": "probe_plan", "params": {
        "trace_ids": record["trace_ids"] + record["probe_trace_ids"]}})
    assert plan.status_code == 202, plan.text
    checked = client.post("/api/v1/jobs", headers=OP, json={"kind": "circuit_program", "params": {
        "import_id": body["import_id"], "closed_loop_job_id": plan.json()["id"]}})
    assert checked.status_code == 422 and "closed_loop" in checked.text, checked.text
    planned = wait_for(client, plan.json()["id"], timeout=600)
    assert planned["status"] == "succeeded", planned["error"]


@pytest.mark.parametrize(("offset", "limit", "rows"), [(0, 40, 40), (480, 40, 20), (500, 40, 0), (20, None, 480)])
def test_the_answer_pages_by_offset_and_limit(offset, limit, rows):
    from app.api.circuit_pages import PAGED, paged

    class Answer:
        pass

    answer = Answer()
    for name in PAGED:
        setattr(answer, name, list(range(500)))
    totals = paged(answer, offset, limit)
    assert totals == dict.fromkeys(PAGED, 500)
    assert answer.traces == list(range(500))[offset:offset + rows] and len(answer.warnings) == rows
