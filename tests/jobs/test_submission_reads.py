"""A job's submission reads its referenced records a table at a time, not one query per
record: a closed loop over 300 traces reads the traces table with as many SQL statements as
one over 3 (a 6,100-trace board loop's submission spent its time in one query per trace,
twice).  Its refusals still name the first offending trace by its index."""

from __future__ import annotations

import threading

import trimesh
from sqlalchemy import event

from tests.conftest import auth
from tests.helpers.jobs import submit

OP = auth("operator")
BOX = trimesh.creation.box(extents=(120.0, 120.0, 4.0))
BOX.apply_translation([60.0, 60.0, 2.0])


def _board(client, count: int) -> tuple[str, list[str], str]:  # type: ignore[no-untyped-def]
    """(part id, ``count`` trace ids on it, a mock machine's id)."""
    part = client.post("/api/v1/parts", files={"file": ("box.stl", BOX.export(file_type="stl"))}, headers=OP).json()
    body = [{"name": f"t{i}", "frame": "xy",
             "geometry": {"type": "line", "start": [5 + (i % 30) * 3, 5 + (i // 30) * 5],
                                                        "end": [6 + (i % 30) * 3, 5 + (i // 30) * 5]}}
            for i in range(count)]
    imported = client.post(f"/api/v1/parts/{part['id']}/traces:import", json=body, headers=OP)
    assert imported.status_code == 201, imported.text
    machine = client.post("/api/v1/machines", json={"name": "m", "port": "mock://", "dialect": "marlin"},
                          headers=OP).json()
    return part["id"], [t["id"] for t in imported.json()["items"]], machine["id"]


def _traces_reads(client, kind: str, params: dict) -> int:  # type: ignore[no-untyped-def]
    """Submit a job in this thread (``Runtime.submit``, what ``POST /jobs`` calls); the SQL
    statements this thread ran on the traces table meanwhile (the service's other threads,
    e.g. a loop already running, are not counted)."""
    runtime = client.app.state.runtime
    here, count = threading.get_ident(), [0]

    def seen(_conn, _cursor, statement: str, *_args) -> None:  # type: ignore[no-untyped-def]
        count[0] += threading.get_ident() == here and "FROM traces" in statement

    event.listen(runtime.engine, "before_cursor_execute", seen)
    try:
        runtime.submit(kind, params)
    finally:
        event.remove(runtime.engine, "before_cursor_execute", seen)
    return count[0]


def _loop(part_id: str, trace_ids: list[str], machine_id: str) -> dict:
    return {"part_id": part_id, "trace_ids": trace_ids, "machine_id": machine_id, "joint_probing": True,
            "pause_at": ["plan"]}


def test_a_board_loops_submission_reads_each_table_once(client):
    part_id, ids, machine_id = _board(client, 300)
    other = client.post("/api/v1/machines", json={"name": "n", "port": "mock://", "dialect": "marlin"},
                        headers=OP).json()["id"]
    few = _traces_reads(client, "closed_loop", _loop(part_id, ids[:3], machine_id))
    many = _traces_reads(client, "closed_loop", _loop(part_id, ids, other))
    assert many == few <= 2, (few, many)  # the references read, then re-read under the lock


def test_the_first_missing_or_repeated_trace_is_named_by_its_index(client):
    part_id, ids, machine_id = _board(client, 40)
    missing = submit(client, "closed_loop", _loop(part_id, ids[:7] + ["trace_nowhere"] + ids[7:], machine_id))
    assert (missing.status_code == 422
            and missing.json()["errors"][0]["loc"] == ["params", "trace_ids", "7"]), missing.text
    twice = submit(client, "closed_loop", _loop(part_id, ids + [ids[12]], machine_id))
    assert twice.status_code == 422 and "listed twice" in twice.text, twice.text
    assert twice.json()["errors"][0]["loc"] == ["params", "trace_ids", "40"], twice.text
    plan_twice = submit(client, "probe_plan", {"trace_ids": ids[:5] + [ids[2]]})
    assert plan_twice.status_code == 422 and plan_twice.json()["errors"][0]["loc"] == ["params", "trace_ids", "5"]


def test_a_board_loops_record_leaves_its_input_hashes_out_unless_asked(client):
    part_id, ids, machine_id = _board(client, 300)
    job = submit(client, "closed_loop", _loop(part_id, ids, machine_id))
    assert job.status_code == 202, job.text
    brief = client.get(f"/api/v1/jobs/{job.json()['id']}", headers=OP)
    record = brief.json()
    assert len(brief.content) <= 12_000, len(brief.content)  # the 301 hashes alone are ~28 KB
    assert record["params"]["trace_ids"] == ids and record["params_omitted"] is None  # 8 KB of ids: under 16 KiB
    assert record["input_hashes"] == {} and record["input_hashes_omitted"] == 301  # the part and each trace
    whole = client.get(f"/api/v1/jobs/{job.json()['id']}", headers=OP, params={"include": "input_hashes"}).json()
    assert set(whole["input_hashes"]) == {f"part:{part_id}", *(f"trace:{t}" for t in ids)}
    assert whole["input_hashes_omitted"] is None
