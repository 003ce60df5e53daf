"""RFC 9457 problem details, built from our exceptions (pure dict helpers)."""

from __future__ import annotations

import json
import math
from typing import Any

from app.domain.errors import Cancelled, Conflict, ConformaError, InvalidInput, NotFound, TooLarge

PROBLEM_MEDIA_TYPE = "application/problem+json"


def _short(value: Any, limit: int = 200) -> Any:
    """A JSON-safe, bounded rendering of an offending value."""
    try:
        text = json.dumps(value, allow_nan=False)
    except (TypeError, ValueError):
        if isinstance(value, float) and not math.isfinite(value):
            return str(value)
        text = json.dumps(repr(value))
    if len(text) > limit:
        return text[:limit] + "..."
    return json.loads(text)


def problem(status: int, title: str, detail: str, *, errors: list[dict[str, Any]] | None = None,
            type_: str | None = None) -> dict[str, Any]:
    body: dict[str, Any] = {
        "type": type_ or f"https://conforma.dev/problems/{status}",
        "title": title,
        "status": status,
        "detail": detail,
    }
    if errors is not None:
        body["errors"] = errors
    return body


# The HTTP meaning of the domain's exception family, kept at the edge (the core raises
# these without knowing HTTP).  Service-side classes outside the core (machines, machine
# jobs) declare their own ``status`` and ``title`` attributes.
_STATUS: dict[type, tuple[int, str]] = {
    InvalidInput: (422, "Unprocessable input"),
    NotFound: (404, "Not found"),
    Conflict: (409, "Conflict"),
    TooLarge: (413, "Payload too large"),
    Cancelled: (409, "Cancelled"),
    ConformaError: (400, "Bad request"),
}


def http_status(exc: ConformaError) -> tuple[int, str]:
    """(status, title) of one of our exceptions: the nearest class in its MRO that the table
    above names or that declares its own ``status``."""
    for cls in type(exc).__mro__:
        if "status" in cls.__dict__:
            return int(cls.__dict__["status"]), str(cls.__dict__.get("title", _STATUS[ConformaError][1]))
        if cls in _STATUS:
            return _STATUS[cls]
    return _STATUS[ConformaError]


def from_error(exc: ConformaError) -> dict[str, Any]:
    """The problem document for one of our exceptions (names field and value)."""
    errors = None
    if exc.field is not None:
        entry: dict[str, Any] = {"loc": exc.field.split("."), "msg": exc.message}
        if exc.value is not None:
            entry["value"] = _short(exc.value)
        errors = [entry]
    status, title = http_status(exc)
    return problem(status, title, exc.message, errors=errors,
                   type_=f"https://conforma.dev/problems/{type(exc).__name__}")
