"""Schemathesis against /openapi.json with every role (viewer, operator, admin keys and no
key): no generated request may produce a server error, and every answer's status code
must be documented for its route (the problem responses of app.api.openapi_errors).
A short run (4 examples per route and role); tests/bench/test_bench_fuzz.py runs long."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck
from hypothesis import settings as hypothesis_settings

from tests.api.fuzz_roles import ROLES, call, cleanup, make_app, schemathesis

APP, _DATA = make_app()
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)  # the document needs no lifespan


@pytest.fixture(scope="module", autouse=True)
def running_app():
    with TestClient(APP):  # runs the lifespan: migrations, runtime, workers
        yield
    cleanup(_DATA)


@pytest.mark.parametrize("role", ROLES)
@schema.parametrize()
@hypothesis_settings(max_examples=4, deadline=None, database=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
def test_no_request_produces_a_server_error_or_an_undocumented_status(case, role):
    call(case, role)
