"""Every error a route can raise is in the OpenAPI document, read from the code itself.

For each documented route, the functions its endpoint calls by name (in ``app``, followed
to any depth) are read: every ``raise SomeConformaError(`` counts with its HTTP status
(``app.platform.problems.http_status``), every ``HTTPException(NNN`` with NNN, and a
``hardware_errors()`` block with every status a hardware error translates to (409, 422,
502, 503: ``app.machines.live.translate``).  Each must be among the route's documented responses.
Calls through attributes (``runtime.machines.require``) are not followed; the schemathesis
run (test_fuzz_openapi.py) checks the answers themselves."""

from __future__ import annotations

import inspect
import re
import types
from collections.abc import Callable
from typing import Any

import pytest
from fastapi.routing import APIRoute

from app.domain.errors import ConformaError
from app.main import create_app
from app.platform.problems import _STATUS

HARDWARE = {409, 422, 502, 503}


def _status(cls: type) -> int:
    for base in cls.__mro__:
        if "status" in base.__dict__:
            return int(base.__dict__["status"])
        if base in _STATUS:
            return _STATUS[base][0]
    raise AssertionError(cls)


def raised(fn: Callable[..., Any], seen: set | None = None) -> dict[int, str]:
    """{status: where it is raised} over ``fn`` and the ``app`` functions it calls by name."""
    seen = set() if seen is None else seen
    if fn in seen:
        return {}
    seen.add(fn)
    try:
        source = inspect.getsource(fn)
    except (OSError, TypeError):
        return {}
    names = getattr(fn, "__globals__", {})
    where = f"{fn.__module__}.{fn.__qualname__}"
    out: dict[int, str] = {}
    for name in re.findall(r"raise (\w+)\(", source):
        cls = names.get(name)
        if isinstance(cls, type) and issubclass(cls, ConformaError):
            out.setdefault(_status(cls), f"{name} in {where}")
    for code in re.findall(r"HTTPException\((\d{3})", source):
        out.setdefault(int(code), f"HTTPException in {where}")
    if "hardware_errors()" in source:
        for code in HARDWARE:
            out.setdefault(code, f"hardware_errors() in {where}")
    for name in set(re.findall(r"\b(\w+)\(", source)):
        called = names.get(name)
        if isinstance(called, types.FunctionType) and called.__module__.startswith("app."):
            for code, place in raised(called, seen).items():
                out.setdefault(code, place)
    return out


def _bare_settings():  # type: ignore[no-untyped-def]
    import tempfile

    from app.platform.config import load_settings

    return load_settings({}, data_dir=tempfile.mkdtemp(prefix="conforma-audit-") + "/data", viewer=False,
                         embedded_worker=False)


APP = create_app(_bare_settings())
DOCUMENT = APP.openapi()
ROUTES = [(route, method) for route in APP.routes if isinstance(route, APIRoute) and route.include_in_schema
          for method in sorted(route.methods)]


@pytest.mark.parametrize(("route", "method"), ROUTES, ids=[f"{m} {r.path}" for r, m in ROUTES])
def test_every_status_a_route_raises_is_documented(route, method):
    documented = {int(code) for code in DOCUMENT["paths"][route.path][method.lower()]["responses"]}
    missing = {code: place for code, place in raised(route.endpoint).items() if code not in documented}
    assert not missing, f"{method} {route.path} can answer {missing} but documents only {sorted(documented)}"


def test_the_audit_sees_what_a_route_raises():
    """The reading itself: a console command reaches the firmware (hardware_errors), a part's
    deletion raises NotFound and Conflict."""
    by_name = {(r.path, m): r for r, m in ROUTES}
    console = raised(by_name[("/api/v1/machines/{machine_id}/command", "POST")].endpoint)
    assert HARDWARE <= set(console)
    assert {404, 409} <= set(raised(by_name[("/api/v1/parts/{part_id}", "DELETE")].endpoint))
