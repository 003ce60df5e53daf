"""JobReads: the named reads a job kind uses, on rows written straight into a fresh database."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import event
from sqlalchemy.orm.exc import DetachedInstanceError
from sqlalchemy.pool import StaticPool
from sqlmodel import Session, SQLModel, create_engine

from app.domain.errors import ConformaError, InvalidInput, NotFound
from app.platform.models import Job, JobReference, Trace
from app.runtime.reads import JobReads

T0 = datetime(2026, 1, 1, tzinfo=UTC)


def _job(job_id: str, kind: str, status: str, **fields: object) -> Job:
    return Job(id=job_id, kind=kind, status=status, params=fields.pop("params", {}), created_at=T0, **fields)


def _trace(trace_id: str, part_id: str, minutes: int, source: dict | None = None) -> Trace:
    return Trace(id=trace_id, part_id=part_id, name=f"name of {trace_id}", frame="part", geometry={},
                 standoff_mm=0.1, length_mm=1.0, z_min=0.0, z_max=0.0, nominal={"points": [[0, 0, 0]]},
                 created_at=T0 + timedelta(minutes=minutes), source=source)


@pytest.fixture
def session() -> Iterator[Session]:
    engine = create_engine("sqlite://", connect_args={"check_same_thread": False}, poolclass=StaticPool)
    SQLModel.metadata.create_all(engine)
    with Session(engine) as session:
        session.add_all([
            _job("slice-ok", "slice", "succeeded"), _job("slice-bad", "slice", "failed"),
            _trace("t-late", "p", 2, {"role": "pad_probe"}), _trace("t-early", "p", 1), _trace("t-other", "q", 0),
            _job("probe-old", "calibrate_probe", "succeeded", machine_id="m", finished_at=T0),
            _job("probe-failed", "calibrate_probe", "failed", machine_id="m"),
            _job("print-running", "print", "running"), _job("print-done", "print", "succeeded"),
            _job("loop", "closed_loop", "running"), _job("child", "probe_run", "succeeded", parent_id="loop"),
        ])
        session.add_all([JobReference(job_id=j, ref_kind="machine", ref_id="m")
                         for j in ("print-running", "print-done")])
        session.commit()
        yield session


def test_a_succeeded_job_of_its_kind_is_returned_and_any_other_is_refused_naming_the_field(session):
    reads = JobReads(session)
    assert reads.succeeded_job("slice-ok", "slice", "params.slice_job_id").id == "slice-ok"
    with pytest.raises(InvalidInput) as failed:
        reads.succeeded_job("slice-bad", "slice", "params.slice_job_id", hint=" (wait for it)")
    assert failed.value.field == "params.slice_job_id" and failed.value.value == "slice-bad"
    assert "failed slice job" in failed.value.message and failed.value.message.endswith("(wait for it)")
    with pytest.raises(InvalidInput):
        reads.succeeded_job("slice-ok", "toolpath", "params.job_id")
    with pytest.raises(NotFound) as missing:
        reads.succeeded_job("nope", "slice", "params.slice_job_id")
    assert missing.value.field == "params.slice_job_id"
    with pytest.raises(ConformaError) as invalid:
        reads.succeeded_job("nope", None, "params.mask", error=ConformaError, missing_is_invalid=True)
    assert type(invalid.value) is ConformaError and invalid.value.field == "params.mask"


def test_records_by_id_name_the_field_and_find_answers_none(session):
    reads = JobReads(session)
    assert reads.job("slice-ok").kind == "slice"
    with pytest.raises(NotFound) as missing:
        reads.machine("m", field="params.machine_id")
    assert (missing.value.field, missing.value.value) == ("params.machine_id", "m")
    assert reads.find_job("nope") is None and reads.find_job(None) is None and reads.find_trace(None) is None


def test_traces_keep_the_asked_order_and_a_missing_one_is_named(session):
    reads = JobReads(session)
    assert [t.id for t in reads.traces(["t-late", "t-other", "t-early"])] == ["t-late", "t-other", "t-early"]
    with pytest.raises(NotFound) as missing:
        reads.traces(["t-late", "gone"])
    assert missing.value.value == "gone"
    assert set(reads.traces_by_id(["t-late", "gone"])) == {"t-late"}
    assert [t.id for t in reads.traces_of_part("p")] == ["t-early", "t-late"]  # oldest first
    assert reads.trace_names(["t-early"]) == {"t-early": "name of t-early"}
    assert reads.trace_sources(["t-late", "t-early"]) == {"t-late": {"role": "pad_probe"}, "t-early": {}}
    [summary] = reads.trace_summaries(["t-late"])
    assert (summary.id, summary.source, summary.nominal) == ("t-late", {"role": "pad_probe"}, {"points": [[0, 0, 0]]})


def test_a_machine_is_held_by_an_active_job_of_the_kinds_but_not_by_the_parent_asking(session):
    assert JobReads(session).machine_holder("m", ("print",)) == {
        "id": "print-running", "kind": "print", "status": "running", "program_state": None}
    assert JobReads(session).machine_holder("m", ("probe_run",)) is None  # another kind
    assert JobReads(session, parent_id="print-running").machine_holder("m", ("print",)) is None
    assert JobReads(session).machine_holder("other", ("print",)) is None


def test_jobs_by_machine_and_by_parent_are_the_succeeded_ones(session):
    reads = JobReads(session)
    [probe] = reads.succeeded_on_machine("m", ("calibrate_probe", "calibrate_nozzle"))
    assert (probe.id, probe.kind, probe.finished_at.replace(tzinfo=UTC)) == ("probe-old", "calibrate_probe", T0)
    assert [j.id for j in reads.succeeded_children("loop")] == ["child"]
    assert reads.succeeded_children("print-running") == []


def test_traces_without_nominals_leave_the_nominal_and_source_unread_and_their_nominals_come_in_one_query():
    engine = create_engine("sqlite://", connect_args={"check_same_thread": False}, poolclass=StaticPool)
    SQLModel.metadata.create_all(engine)
    with Session(engine) as session:
        session.add_all([_trace("t-1", "p", 1, {"net": "GND"}), _trace("t-2", "p", 2)])
        session.commit()
    statements: list[str] = []
    event.listen(engine, "before_cursor_execute", lambda *args: statements.append(args[2]))
    with Session(engine) as session:
        traces = JobReads(session).traces(["t-2", "t-1"], nominals=False)
        assert [t.id for t in traces] == ["t-2", "t-1"] and len(statements) == 1
        assert "nominal" not in statements[0] and "source" not in statements[0] and "geometry" in statements[0]
        assert traces[0].standoff_mm == 0.1 and traces[0].geometry == {} and len(statements) == 1
        nominals = JobReads(session).trace_nominals(["t-1", "t-2", "gone"])
        assert nominals == {"t-1": {"points": [[0, 0, 0]]}, "t-2": {"points": [[0, 0, 0]]}} and len(statements) == 2
    with pytest.raises(DetachedInstanceError):  # never read by accident once the session has closed
        _ = traces[1].nominal
