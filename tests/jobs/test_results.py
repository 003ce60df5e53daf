"""Typed job results: written and read through one model per kind, so a renamed field fails
loudly on both sides instead of reading as an empty default."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from app.jobs.results.models import (
    CompensateResult,
    ProbePlanResult,
    ProbeRunResult,
    ReconstructResult,
    StoredResultError,
    joint_trace_ranges,
)
from app.platform.models import Job, utcnow

JOINT_PLAN = {
    "count": 3, "method": "kriging", "points": [[0.0, 0.0, 1.0], [1.0, 0.0, 1.5], [5.0, 5.0, 2.0]],
    "s_mm": [0.0, 1.0, 0.0], "records": [{"index": 0}, {"index": 1}, {"index": 2}], "program": {"lines": 9},
    "traces": [{"trace_id": "a", "first": 0, "count": 2, "s_mm": [0.0, 1.0], "trace_length_mm": 4.0,
                "predicted_sd_mm": None},
               {"trace_id": "b", "first": 2, "count": 1, "s_mm": [0.0], "trace_length_mm": 3.0,
                "predicted_sd_mm": 0.002}],
}
RUN = {"points": [{"index": 0, "nominal": [0.0, 0.0, 1.0], "measured": [0.0, 0.0, 1.01], "deviation_mm": 0.01}],
       "resumes": 0, "stats": {"count": 1, "max_abs_mm": 0.01, "mean_mm": 0.01, "rms_mm": 0.01}}


def _job(kind: str, result: dict, params: dict | None = None) -> Job:
    return Job(id=f"job_{kind}", kind=kind, status="succeeded", params=params or {}, result=result,
               created_at=utcnow())


def test_a_result_is_stored_as_written_and_read_by_attribute():
    assert ProbePlanResult.written(JOINT_PLAN) == JOINT_PLAN  # only the keys given, values unchanged
    assert ProbeRunResult.written(RUN) == RUN
    plan = ProbePlanResult.of(_job("probe_plan", JOINT_PLAN))
    assert plan.points[2] == [5.0, 5.0, 2.0] and plan.traces is not None and plan.traces[1].trace_id == "b"
    assert joint_trace_ranges(_job("probe_plan", JOINT_PLAN, {"trace_ids": ["a", "b"]})) == {"a": (0, 2), "b": (2, 3)}
    assert ProbeRunResult.of(_job("probe_run", RUN)).points[0].measured == [0.0, 0.0, 1.01]


def test_a_writer_that_renames_a_field_fails_the_job():
    renamed = {("point" if k == "points" else k): v for k, v in RUN.items()}
    with pytest.raises(ValidationError, match="point"):
        ProbeRunResult.written(renamed)
    with pytest.raises(ValidationError):
        ReconstructResult.written({"method": "deviation"})  # most of a reconstruction missing


def test_a_reader_of_a_renamed_field_fails_loudly():
    """Before: ``(plan.result or {}).get("traces", [])`` read a renamed ``traces`` as no traces,
    so a joint plan's runs were silently taken as one trace's."""
    renamed = {("trace_ranges" if k == "traces" else k): v for k, v in JOINT_PLAN.items()}
    with pytest.raises(StoredResultError, match="trace_ranges") as caught:
        joint_trace_ranges(_job("probe_plan", renamed, {"trace_ids": ["a", "b"]}))
    assert caught.value.field == "result.trace_ranges"
    compensated = {"points": [[0.0, 0.0, 1.1]]}
    with pytest.raises(StoredResultError, match="CompensateResult"):
        CompensateResult.of(_job("compensate", compensated))
    with pytest.raises(StoredResultError, match="not a probe_run job"):
        ProbeRunResult.of(_job("probe_plan", JOINT_PLAN))
