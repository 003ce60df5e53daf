"""Every route's error answers in the OpenAPI document, derived from what guards it.

The codes come from the layers a request passes, so they cannot drift from the code:
keyed routes answer 401 and 429 (throttled failed keys), 403 when they need more than the
viewer role; routes with path parameters 404; routes with parameters or a body 422; routes
with a body 400 (unparsable) and 413 (and 401 before the body is read); creating and deleting routes 409
(a conflicting state or Idempotency-Key); every admitted route 503 with Retry-After.
Codes a router declares itself keep their description.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from fastapi import APIRouter
from fastapi.routing import APIRoute

from app.api.admission import _EXEMPT

PROBLEM_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "RFC 9457 problem details",
    "required": ["type", "title", "status", "detail"],
    "properties": {
        "type": {"type": "string"}, "title": {"type": "string"}, "status": {"type": "integer"},
        "detail": {"type": "string"},
        "errors": {"type": "array", "description": "the offending fields and values", "items": {
            "type": "object", "required": ["loc", "msg"],
            "properties": {"loc": {"type": "array", "items": {"type": "string"}}, "msg": {"type": "string"},
                           "value": {}},
        }},
    },
}


_DESCRIPTIONS = {
    400: "the body cannot be parsed (not UTF-8, not JSON, broken multipart)",
    401: "no API key, or an unknown or revoked one",
    403: "the key's role is not allowed to do this",
    404: "a record named in the path does not exist",
    409: "conflicts with the current state (a reference, a running job, a reused Idempotency-Key)",
    413: "the body exceeds the size limit",
    422: "a parameter or field is invalid (the problem names it and the value)",
    429: "too many failed API key attempts from this address (see Retry-After)",
    502: "the machine's firmware halted, raised an alarm, or answered nonsense",
    503: "the server is at capacity (see Retry-After)",
}


def _needed_role(route: APIRoute) -> str | None:
    """The role the route's key check asks for (None for routes without a key)."""
    for dependency in route.dependant.dependencies:
        need = getattr(dependency.call, "needs_role", None)
        if need is not None:
            return need
    return None


def error_codes(route: APIRoute) -> set[int]:
    """The 4xx/5xx codes ``route`` can answer from the guards in front of it."""
    codes: set[int] = set()
    need = _needed_role(route)
    if need is not None:
        codes |= {401, 429}
        if need != "viewer":
            codes.add(403)
    if not _EXEMPT.match(route.path):
        codes.add(503)
    dependant = route.dependant
    if dependant.path_params:
        codes.add(404)
    if dependant.path_params or dependant.query_params or dependant.header_params or dependant.body_params:
        codes.add(422)
    if dependant.body_params:
        codes |= {400, 401, 413}
    if (route.methods or set()) & {"POST", "DELETE"} and need is not None:
        codes.add(409)
    if route.path.startswith("/api/v1/machines/{machine_id}/") and "POST" in (route.methods or set()):
        codes.add(502)  # it talks to the machine's firmware (MachineFault)
    return codes


def document_error_responses(routers: Iterable[APIRouter]) -> None:
    """Add the problem responses of every route of ``routers`` to the OpenAPI document."""
    for route in (r for router in routers for r in router.routes):
        if not isinstance(route, APIRoute):
            continue
        for code in sorted(error_codes(route)):
            entry = route.responses.setdefault(code, {})
            entry.setdefault("description", _DESCRIPTIONS[code])
            entry.setdefault("content", {"application/problem+json": {"schema": PROBLEM_SCHEMA}})
