"""The surface-fit package's small exception family (all HTTP 422)."""

from __future__ import annotations

from typing import Any

from app.domain.errors import InvalidInput
from app.five_axis.errors import short

__all__ = ["SurfaceFitError", "GridHoleError"]


class SurfaceFitError(InvalidInput):
    """Measurement data or fit parameters that cannot be used."""

    def __init__(self, message: str, *, field: str | None = None, value: Any = None) -> None:
        super().__init__(message, field=field, value=short(value))


class GridHoleError(SurfaceFitError):
    """A measurement grid with missing (NaN) heights while the hole policy is "error"."""
