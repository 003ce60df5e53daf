"""The geometry core's small exception family (all map to HTTP 422).

Every error names the offending input ``field`` (a dotted path such as
``"geometry.knots"``) and a short JSON-friendly ``value``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.domain.errors import InvalidInput

__all__ = [
    "GeometryError",
    "DegenerateGeometryError",
    "KnotVectorError",
    "WeightError",
    "OffSurfaceError",
    "short_value",
]


def short_value(value: Any, limit: int = 8, digits: int | None = None) -> Any:
    """Make ``value`` JSON-friendly and short: arrays become (clipped) lists of floats, rounded
    to ``digits`` decimals when given."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float):
        if not np.isfinite(value):
            return str(value)
        return value if digits is None else round(value, digits)
    if isinstance(value, (list, tuple)):
        items = [short_value(v, limit, digits) for v in list(value)[:limit]]
        if len(value) > limit:
            items.append(f"... ({len(value)} items)")
        return items
    if isinstance(value, (int, str, bool)) or value is None:
        return value
    return str(value)[:80]


class GeometryError(InvalidInput):
    """Geometry input that cannot be used; ``field`` and ``value`` say which and why."""

    def __init__(self, message: str, *, field: str | None = None, value: Any = None) -> None:
        super().__init__(message, field=field, value=short_value(value))


class DegenerateGeometryError(GeometryError):
    """Zero length, too few points, duplicate points, non-finite coordinates."""


class KnotVectorError(GeometryError):
    """A knot vector of the wrong length, decreasing, or not matching the degree."""


class WeightError(GeometryError):
    """Non-positive, non-finite or wrongly sized NURBS weights."""


class OffSurfaceError(GeometryError):
    """A trace (or point) is not over / not on the part's surface.

    The message and ``value`` give the first offending coordinate.
    """
