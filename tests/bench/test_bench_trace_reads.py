"""Bench: a board job's read of its 1000 traces once its process holds their nominals.

Run: .venv/bin/python -m pytest tests/bench/test_bench_trace_reads.py -s -o addopts="" -q -n 0

The dome's 1000-trace board stored in a fresh SQLite file (the draped nominals as the service
stores them), read as a board job reads them, the nominals already held by the process
(:mod:`app.jobs.held_nominals`): with their nominal columns (each row's JSON decoded, then
found held) and without them (:func:`app.jobs.inputs.placed_nominals`: only the ones not
held are read).  Process CPU s, median of 7 in alternation (the box is shared)."""

from __future__ import annotations

import statistics
import time
from datetime import UTC, datetime
from pathlib import Path

from sqlmodel import Session, SQLModel, create_engine

from app.jobs.inputs import placed_nominal, placed_nominals
from app.platform.models import Trace
from app.reference.boards import board_path, board_traces, dome_part
from app.runtime.reads import JobReads

TRACES = 1000


def test_a_board_jobs_read_of_held_traces(tmp_path: Path):
    part = dome_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, TRACES)]
    engine = create_engine(f"sqlite:///{tmp_path / 'traces.db'}")
    SQLModel.metadata.create_all(engine)
    ids = [f"bench_trace_{i}" for i in range(TRACES)]
    with Session(engine) as session:
        session.add_all([Trace(id=t, part_id="p", name=t, frame="xy", geometry={"kind": "arc"}, standoff_mm=0.1,
                               length_mm=p.length_mm, z_min=0.0, z_max=1.0, nominal=p.to_dict(), source={"net": "N"},
                               created_at=datetime(2026, 1, 1, tzinfo=UTC)) for t, p in zip(ids, paths)])
        session.commit()

    class Reads:
        def trace_nominals(self, trace_ids: list[str]) -> dict:
            with Session(engine) as session:
                return JobReads(session).trace_nominals(trace_ids)

    def with_nominals() -> list:
        with Session(engine) as session:
            traces = JobReads(session).traces(ids)
        return [placed_nominal(t, None) for t in traces]

    def without_nominals() -> list:
        with Session(engine) as session:
            traces = JobReads(session).traces(ids, nominals=False)
        return placed_nominals(Reads(), traces, None)  # type: ignore[arg-type]

    first = with_nominals()
    assert all(a is b for a, b in zip(first, without_nominals()))  # the same held polylines
    runs: dict[str, list[float]] = {"with": [], "without": []}
    for _ in range(7):
        for name, read in (("with", with_nominals), ("without", without_nominals)):
            c0 = time.process_time()
            read()
            runs[name].append(time.process_time() - c0)
    with_s, without_s = statistics.median(runs["with"]), statistics.median(runs["without"])
    print(f"\nread of {TRACES} held traces: with their nominals {with_s:.3f} s CPU, without {without_s:.3f} s "
          f"({with_s / without_s:.0f} x)")
    assert without_s < with_s
