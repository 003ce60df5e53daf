"""RFC 9457 problem details, built from our exceptions (pure dict helpers)."""

from __future__ import annotations

import json
import math
from typing import Any

from app.errors import ConformaError

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


def from_error(exc: ConformaError) -> dict[str, Any]:
    """The problem document for one of our exceptions (names field and value)."""
    errors = None
    if exc.field is not None:
        entry: dict[str, Any] = {"loc": exc.field.split("."), "msg": exc.message}
        if exc.value is not None:
            entry["value"] = _short(exc.value)
        errors = [entry]
    return problem(exc.status, exc.title, exc.message, errors=errors,
                   type_=f"https://conforma.dev/problems/{type(exc).__name__}")
