"""Schemathesis against /openapi.json with every role (viewer, operator, admin keys and no
key): no generated request may produce a server error, and every answer's status code
must be documented for its route (the problem responses of app.api.openapi_errors).
A short run; tests/bench/test_bench_fuzz.py runs long (150 examples, every phase and role).

Two phases: the fuzzing phase (4 random examples per route) with every role, and the
coverage phase (schemathesis' deterministic boundary, missing-field and wrong-type cases:
~4,000 requests a role, most of this file's time) with the operator and admin keys only.
A viewer's or a keyless request runs no code that the admin's does not, but the key and role
checks: without a key the request is refused before the route (``app.api.limits``), and with
the viewer key a route runs its handler as for any role it admits (the handlers read the
role only to refuse an operator's ``force=true``, so the operator's key runs the coverage
phase too) or refuses it at the role check; those refusals are what the fuzzing phase
checks on every route for both roles."""

from __future__ import annotations

import copy
import dataclasses

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck
from hypothesis import settings as hypothesis_settings

from tests.api.fuzz_roles import ROLES, call, cleanup, make_app, schemathesis

APP, _DATA = make_app()
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)  # the document needs no lifespan
HANDLER_ROLES = ("operator", "admin")  # every phase
CHECKED_ROLES = ("viewer", None)       # the fuzzing phase
assert {*HANDLER_ROLES, *CHECKED_ROLES} == set(ROLES) and len(ROLES) == 4

_config = copy.copy(schema.config)
_config.phases = copy.deepcopy(schema.config.phases)
_config.phases.coverage.enabled = False
fuzzing_schema = dataclasses.replace(schema, config=_config)


@pytest.fixture(scope="module", autouse=True)
def running_app():
    with TestClient(APP):  # runs the lifespan: migrations, runtime, workers
        yield
    cleanup(_DATA)


@pytest.mark.parametrize("role", HANDLER_ROLES)
@schema.parametrize()
@hypothesis_settings(max_examples=4, deadline=None, database=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
def test_no_request_produces_a_server_error_or_an_undocumented_status(case, role):
    call(case, role)


@pytest.mark.parametrize("role", CHECKED_ROLES)
@fuzzing_schema.parametrize()
@hypothesis_settings(max_examples=4, deadline=None, database=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
def test_no_viewer_or_keyless_request_produces_a_server_error_or_an_undocumented_status(case, role):
    assert case.meta.phase.name.value != "coverage"
    call(case, role)
