"""The long schemathesis run: every route with every role (viewer, operator, admin keys and
no key), 150 examples each: no server error, and every status code documented for its
route.  The default suite runs the same with 4 examples (tests/api/test_fuzz_openapi.py)."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck
from hypothesis import settings as hypothesis_settings

from tests.api.fuzz_roles import ROLES, call, cleanup, make_app, schemathesis

APP, _DATA = make_app()
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)


@pytest.fixture(scope="module", autouse=True)
def running_app():
    with TestClient(APP):
        yield
    cleanup(_DATA)


@pytest.mark.parametrize("role", ROLES)
@schema.parametrize()
@hypothesis_settings(max_examples=150, deadline=None, database=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
def test_long_fuzz_no_server_error_or_undocumented_status(case, role):
    call(case, role)
