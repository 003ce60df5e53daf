"""Schemathesis over every route with every role (shared by the default suite's short run
and tests/bench's long one): no server error, and every status code answered is one the
OpenAPI document lists for that route."""

from __future__ import annotations

import shutil
import tempfile
from collections import Counter
from pathlib import Path

import schemathesis
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import status_code_conformance

from app.main import create_app
from app.platform.config import load_settings
from tests.conftest import KEYS

ROLES = ("viewer", "operator", "admin", None)  # None: no key at all
CHECKS = [not_a_server_error, status_code_conformance]
ANSWERS: Counter = Counter()  # status code -> count, over the whole run


def make_app():  # type: ignore[no-untyped-def]
    data = Path(tempfile.mkdtemp(prefix="conforma-fuzz-"))
    app = create_app(load_settings(
        {}, data_dir=data / "data", viewer=False, embedded_worker=False,
        api_keys=",".join(f"{k}:{r}" for r, k in KEYS.items()), job_plugins="tests.jobs.sample_kinds",
    ))
    return app, data


def call(case, role: str | None):  # type: ignore[no-untyped-def]
    """Send ``case`` with ``role``'s key and check it."""
    if case.path.endswith("/events"):
        case.path_parameters = {"job_id": "job_does_not_exist"}  # a live stream would never end
    headers = {"Authorization": f"Bearer {KEYS[role]}"} if role else {}
    response = case.call(headers=headers)
    ANSWERS[response.status_code] += 1
    case.validate_response(response, checks=CHECKS)
    return response


def cleanup(data: Path) -> None:
    print(f"\nschemathesis answers by status: {dict(sorted(ANSWERS.items()))} ({sum(ANSWERS.values())} requests)")
    shutil.rmtree(data, ignore_errors=True)


__all__ = ["ANSWERS", "ROLES", "call", "cleanup", "make_app", "schemathesis"]
