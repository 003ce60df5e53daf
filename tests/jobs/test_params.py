"""What the kinds share about their parameters: one list of G-code dialects (each kind's subset
follows from a capability in the writer's dialect table, a bad one is a 422 naming the field
and the value) and one standoff resolution (the job's, else the trace's, else one default)."""

from __future__ import annotations

import pytest

from app.compensation.standoff import DEFAULT_STANDOFF_MM, CompensationParams
from app.gcode.writer import DIALECT_NAMES, DIALECTS, DISPENSING_DIALECTS, GcodeError, own_dispense
from app.jobs.params import standoff_of
from tests.conftest import auth
from tests.helpers.jobs import submit

# a kind, enough parameters to pass validation up to the dialect, and the dialects it may write
DIALECT_FIELDS = {
    "compensate": ({"trace_id": "trc_none", "reconstruct_job_id": "job_none"}, DISPENSING_DIALECTS),
    "toolpath": ({"slice_job_id": "job_none"}, DISPENSING_DIALECTS),
    "five_axis": ({"part_id": "prt_none", "trace_id": "trc_none"}, DIALECT_NAMES),
    "probe_plan": ({"trace_id": "trc_none"}, DIALECT_NAMES),
}


def test_the_dispensing_dialects_are_those_with_their_own_dispenser_commands():
    assert DISPENSING_DIALECTS == ("marlin", "grbl")  # LinuxCNC's outputs are numbered: a profile's
    assert set(DIALECT_NAMES) == set(DIALECTS) and set(DISPENSING_DIALECTS) < set(DIALECT_NAMES)
    assert own_dispense("grbl") == ("M8", "M9")
    with pytest.raises(GcodeError) as caught:
        own_dispense("linuxcnc")
    assert caught.value.field == "dialect" and caught.value.value == "linuxcnc"


@pytest.mark.parametrize("kind", sorted(DIALECT_FIELDS))
def test_a_kind_offers_its_dialects_and_names_a_bad_one(client, kind):
    params, allowed = DIALECT_FIELDS[kind]
    schemas = {k["name"]: k["params_schema"] for k in client.get("/api/v1/job-kinds", headers=auth("viewer")).json()}
    assert schemas[kind]["properties"]["dialect"]["enum"] == list(allowed)
    for name in set(DIALECT_NAMES) - set(allowed) | {"smoothie"}:
        refused = submit(client, kind, {**params, "dialect": name})
        assert refused.status_code == 422, refused.text
        body = refused.json()
        assert body["errors"][0]["loc"] == ["params", "dialect"] and body["errors"][0]["value"] == name
        assert "params.dialect" in body["detail"] and name in body["detail"]


def test_the_standoff_is_the_jobs_else_the_traces_else_the_default():
    assert standoff_of(0.25, 0.05) == 0.25
    assert standoff_of(None, 0.05) == 0.05
    assert standoff_of(None, None) == DEFAULT_STANDOFF_MM == CompensationParams().standoff_mm


def test_the_default_standoff_is_the_new_traces_and_the_imports(client):
    schema = client.get("/openapi.json").json()["components"]["schemas"]
    assert schema["TraceCreate"]["properties"]["standoff_mm"]["default"] == DEFAULT_STANDOFF_MM
