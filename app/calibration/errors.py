"""The calibration core's small exception family (maps to HTTP 422).

Every error names the offending input ``field`` (a dotted path such as
``"readings[12]"``) and a short JSON-friendly ``value``.
"""

from __future__ import annotations

from typing import Any

from app.domain.errors import InvalidInput
from app.geometry.errors import short_value as _short

__all__ = ["CalibrationError", "short_value"]


def short_value(value: Any, limit: int = 8) -> Any:
    """The geometry core's short JSON-friendly value, floats rounded to 6 decimals (1 nm)."""
    return _short(value, limit, digits=6)


class CalibrationError(InvalidInput, ValueError):
    """Calibration input (a plan, readings, a model) that cannot be used (422).

    ``field`` names the input (``"readings[7]"`` for the 8th touch), ``value`` the offending value.
    """

    def __init__(self, message: str, *, field: str | None = None, value: Any = None) -> None:
        super().__init__(message, field=field, value=short_value(value))
