"""Schemathesis against /openapi.json: no generated request may produce a 500."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck
from hypothesis import settings as hypothesis_settings
from schemathesis.checks import not_a_server_error

from app.config import load_settings
from app.main import create_app
from tests.conftest import KEYS, auth


_DATA = Path(tempfile.mkdtemp(prefix="conforma-fuzz-"))
APP = create_app(load_settings(
    {}, data_dir=_DATA / "data", viewer=False,
    api_keys=",".join(f"{k}:{r}" for r, k in KEYS.items()), job_plugins="tests.jobs.sample_kinds",
))
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)  # the document needs no lifespan


@pytest.fixture(scope="module", autouse=True)
def running_app():
    with TestClient(APP):  # runs the lifespan: migrations, runtime, workers
        yield
    shutil.rmtree(_DATA, ignore_errors=True)


@schema.parametrize()
@hypothesis_settings(max_examples=30, deadline=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
def test_no_request_produces_a_server_error(case):
    if case.path.endswith("/events"):
        case.path_parameters = {"job_id": "job_does_not_exist"}  # a live stream would never end
    response = case.call(headers=auth("admin"))
    case.validate_response(response, checks=[not_a_server_error])
