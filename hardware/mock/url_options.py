"""Values of a mock device's URL options (``mock://``, ``lkg://`` ... query strings)."""

from __future__ import annotations

import math

from ..errors import InvalidConfig


def url_numbers(key: str, text: str, count: int, device: str) -> tuple[float, ...]:
    """``count`` comma-separated finite numbers of option ``key`` (``InvalidConfig`` naming
    ``port.<key>`` otherwise); ``device`` names whose option it is in the message."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise InvalidConfig(f"{device} option {key}={text!r}: expected {count} comma-separated numbers",
                            field=f"port.{key}", value=text[:60])
    return values
