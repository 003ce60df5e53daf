"""The five-axis package's small exception family (all HTTP 422)."""

from __future__ import annotations

from typing import Any

import numpy as np

from app.domain.errors import InvalidInput

__all__ = ["FiveAxisError", "AxisLimitError", "TraceOffSurfaceError", "DegenerateTraceError",
           "short"]


def short(value: Any, limit: int = 6) -> Any:
    """JSON-friendly, short version of ``value`` (floats rounded, arrays clipped)."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float):
        return round(value, 6) if np.isfinite(value) else str(value)
    if isinstance(value, dict):
        return {str(k): short(v, limit) for k, v in list(value.items())[:limit]}
    if isinstance(value, (list, tuple)):
        return [short(v, limit) for v in list(value)[:limit]]
    return value


class FiveAxisError(InvalidInput):
    """Input for a five-axis plan that cannot be used."""

    def __init__(self, message: str, *, field: str | None = None, value: Any = None) -> None:
        super().__init__(message, field=field, value=short(value))


class AxisLimitError(FiveAxisError):
    """A required pose needs a rotary angle beyond the machine's configured limits."""


class TraceOffSurfaceError(FiveAxisError):
    """The trace leaves the fitted surface (its points are too far from it)."""


class DegenerateTraceError(FiveAxisError):
    """A trace that cannot be followed (zero length, straight where a curvature is needed)."""
