"""A job's record stays small however large its result and parameters: a board-shaped
job's ``GET /jobs/{id}`` (1000 and 6,100 traces) is at most 50 KB, with the result whole
behind ``?include=result``, the trace ids behind ``?include=params`` and every artifact
behind ``?include=artifacts``."""

from __future__ import annotations

import json

from app.api.job_results import ARTIFACTS_INLINE_MAX, PARAMS_INLINE_MAX_BYTES, RESULT_INLINE_MAX_BYTES
from app.jobs.results.models import result_summary
from tests.conftest import auth
from tests.helpers.jobs import submit, wait_for

OP = auth("operator")
TRACES = 1000
POINTS = 100


def _ids(traces: int) -> list[str]:
    return [f"trc_{k:016x}" for k in range(traces)]


def _board_job(client, traces: int = TRACES, artifacts_per_trace: int = 2,  # type: ignore[no-untyped-def]
               points: int = POINTS) -> str:
    response = submit(client, "test_board_result", {"trace_ids": _ids(traces), "points": points,
                                                    "artifacts_per_trace": artifacts_per_trace})
    assert response.status_code == 202, response.text
    job_id: str = response.json()["id"]
    wait_for(client, job_id, timeout=300)
    return job_id


def test_a_board_jobs_record_is_small_and_the_result_whole_on_request(client):
    job_id = _board_job(client)
    brief = client.get(f"/api/v1/jobs/{job_id}", headers=OP)
    assert brief.status_code == 200
    assert len(brief.content) <= 50_000, len(brief.content)
    record = brief.json()
    assert record["status"] == "succeeded"
    assert record["result"] is None and record["result_omitted"] is True
    assert record["result_summary"] == {"board": True, "traces_count": TRACES,
                                        "deviation": {"max_mm": 0.002, "rms_mm": 0.001}}
    assert record["artifact_count"] == 2 * TRACES
    assert len(record["artifacts"]) == ARTIFACTS_INLINE_MAX
    assert record["artifacts"][0]["name"] == "print.trc_0000000000000000.gcode"
    # the 1000 trace ids (23 KB of JSON) are left out; the small parameters stay
    assert record["params"] == {"points": POINTS, "artifacts_per_trace": 2} and record["params_omitted"] == {
        "trace_ids": TRACES}

    whole = client.get(f"/api/v1/jobs/{job_id}", params={"include": "result"}, headers=OP).json()
    assert whole["result_omitted"] is False and whole["result_summary"] is None
    assert len(whole["result"]["traces"]) == TRACES
    assert whole["result"]["traces"][7]["points"][3] == [0.30000000000000004, 0.07, 10.0003]
    assert whole["result_bytes"] == record["result_bytes"] == len(json.dumps(whole["result"]).encode())
    assert len(whole["artifacts"]) == ARTIFACTS_INLINE_MAX  # result only: artifacts and params still in brief
    assert whole["params_omitted"] == {"trace_ids": TRACES} and "trace_ids" not in whole["params"]

    both = client.get(f"/api/v1/jobs/{job_id}?include=result&include=artifacts", headers=OP).json()
    assert len(both["artifacts"]) == 2 * TRACES and both["result"] == whole["result"]
    listed = client.get(f"/api/v1/jobs/{job_id}/artifacts", headers=OP).json()
    assert [a["name"] for a in listed] == [a["name"] for a in both["artifacts"]]

    page = client.get("/api/v1/jobs", params={"kind": "test_board_result"}, headers=OP).json()
    assert page["items"][0]["result"] is None and page["items"][0]["result_summary"] == record["result_summary"]
    assert (page["items"][0]["params"] == record["params"]
            and page["items"][0]["params_omitted"] == {"trace_ids": TRACES})
    full_page = client.get("/api/v1/jobs", params={"kind": "test_board_result", "include": "result"}, headers=OP).json()
    assert full_page["items"][0]["result"] == whole["result"]


def test_a_6100_trace_jobs_record_is_small_and_its_params_whole_on_request(client):
    job_id = _board_job(client, traces=6100, artifacts_per_trace=0, points=2)
    brief = client.get(f"/api/v1/jobs/{job_id}", headers=OP)
    assert brief.status_code == 200 and len(brief.content) <= 50_000, len(brief.content)
    assert brief.json()["params_omitted"] == {"trace_ids": 6100} and "trace_ids" not in brief.json()["params"]
    whole = client.get(f"/api/v1/jobs/{job_id}", params={"include": "params"}, headers=OP).json()
    assert whole["params"]["trace_ids"] == _ids(6100) and whole["params_omitted"] is None
    assert whole["result"] is None and whole["result_omitted"] is True  # params only: the result still in brief
    listed = client.get("/api/v1/jobs", params={"kind": "test_board_result", "include": "params"}, headers=OP).json()
    assert listed["items"][0]["params"]["trace_ids"] == _ids(6100)


def test_a_small_result_is_inlined_and_a_bad_include_is_named(client):
    job_id = _board_job(client, traces=3, artifacts_per_trace=1)
    record = client.get(f"/api/v1/jobs/{job_id}", headers=OP).json()
    assert record["result_bytes"] <= RESULT_INLINE_MAX_BYTES
    assert record["params"]["trace_ids"] == _ids(3) and record["params_omitted"] is None
    assert len(json.dumps(record["params"])) <= PARAMS_INLINE_MAX_BYTES
    assert record["result_omitted"] is False and len(record["result"]["traces"]) == 3
    assert record["artifact_count"] == 3 and len(record["artifacts"]) == 3
    bad = client.get(f"/api/v1/jobs/{job_id}", params={"include": "everything"}, headers=OP)
    assert bad.status_code == 422 and "include" in bad.text and "everything" in bad.text


def test_the_openapi_document_describes_include(client):
    spec = client.get("/openapi.json").json()
    for path in ("/api/v1/jobs/{job_id}", "/api/v1/jobs"):
        params = {p["name"]: p for p in spec["paths"][path]["get"]["parameters"]}
        assert "include" in params, path
        schema = json.dumps(params["include"]["schema"])
        assert "result" in schema and "artifacts" in schema and "params" in schema
        assert ("result_omitted" in params["include"]["description"]
                and "params_omitted" in params["include"]["description"])


def test_a_summary_keeps_scalars_declared_fields_and_list_lengths():
    result = {"board": True, "count": 3, "name": "x", "missing": None, "traces": [{}, {}], "nested": {"a": 1},
              "deviation": {"max_mm": 1.0}}
    assert result_summary("test_board_result", result) == {"board": True, "count": 3, "name": "x", "missing": None,
                                                            "traces_count": 2, "deviation": {"max_mm": 1.0}}
    # an undeclared kind keeps no nested objects; a declared field larger than 4 KiB is left out
    assert result_summary("slice_of_nothing", result) == {"board": True, "count": 3, "name": "x", "missing": None,
                                                           "traces_count": 2}
    assert result_summary("test_board_result", {"deviation": {"samples": list(range(2000))}}) == {}
    assert result_summary("test_board_result", None) is None
