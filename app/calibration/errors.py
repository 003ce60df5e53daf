"""The calibration core's small exception family (maps to HTTP 422).

Every error names the offending input ``field`` (a dotted path such as
``"readings[12]"``) and a short JSON-friendly ``value``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.errors import InvalidInput

__all__ = ["CalibrationError", "short_value"]


def short_value(value: Any, limit: int = 8) -> Any:
    """Make ``value`` JSON-friendly and short: arrays become (clipped) lists of rounded floats."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float):
        return round(value, 6) if np.isfinite(value) else str(value)
    if isinstance(value, (list, tuple)):
        items = [short_value(v, limit) for v in list(value)[:limit]]
        if len(value) > limit:
            items.append(f"... ({len(value)} items)")
        return items
    if isinstance(value, (int, str, bool)) or value is None:
        return value
    return str(value)[:80]


class CalibrationError(InvalidInput, ValueError):
    """Calibration input (a plan, readings, a model) that cannot be used (422).

    ``field`` names the input (``"readings[7]"`` for the 8th touch), ``value`` the offending value.
    """

    def __init__(self, message: str, *, field: str | None = None, value: Any = None) -> None:
        super().__init__(message, field=field, value=short_value(value))
