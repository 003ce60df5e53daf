"""A submission reads its referenced records in one query per table, leaving a trace's nominal unread."""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import event
from sqlalchemy.pool import StaticPool
from sqlmodel import Session, SQLModel, create_engine

from app.platform.models import Trace
from app.runtime.engine import _preload

NOMINAL = {"points": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]}


def test_the_referenced_traces_are_read_at_once_without_their_nominals_which_load_when_read():
    engine = create_engine("sqlite://", connect_args={"check_same_thread": False}, poolclass=StaticPool)
    SQLModel.metadata.create_all(engine)
    ids = [f"trace_{i}" for i in range(5)]
    with Session(engine) as session:
        session.add_all([Trace(id=t, part_id="p", name=t, frame="part", geometry={"kind": "line"}, standoff_mm=0.1,
                               length_mm=1.0, z_min=0.0, z_max=0.0, nominal=NOMINAL, source={"net": "GND"},
                               created_at=datetime(2026, 1, 1, tzinfo=UTC)) for t in ids])
        session.commit()
    statements: list[str] = []
    event.listen(engine, "before_cursor_execute", lambda *args: statements.append(args[2]))
    with Session(engine) as session:
        held = _preload(session, [("part", "p"), *(("trace", t) for t in ids)])
        assert sorted(t.id for t in held) == ids and len(statements) == 1
        assert "nominal" not in statements[0] and "geometry" in statements[0]   # the input hash reads the geometry
        trace = session.get(Trace, ids[2])
        assert trace is held[[t.id for t in held].index(ids[2])] and len(statements) == 1   # found in the session
        assert trace.geometry == {"kind": "line"} and len(statements) == 1
        assert trace.nominal == NOMINAL and trace.source == {"net": "GND"}   # a check that reads it loads it
