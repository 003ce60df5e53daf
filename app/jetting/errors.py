"""The jetting package's exception family (pure; maps to HTTP 422)."""

from __future__ import annotations

from app.domain.errors import InvalidInput


class JettingError(InvalidInput):
    """Jetting input that cannot be used: bad mask, drop larger than the part, too much memory.

    Raised before any simulation or solve starts; ``field`` names the input (for example
    ``"target.mask"`` or ``"drop.dpi"``) and ``value`` the offending value.
    """
