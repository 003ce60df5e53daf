"""Shared parameter checks for the frozen parameter dataclasses of the pure core.

Each check reads the named attributes of a parameter object in order and raises the
caller's error type for the first bad one, naming it: ``field`` is ``prefix + name``
(e.g. ``"params.feed_mm_min"``) and ``value`` the offending value.  A number here is a
real number (Python or NumPy int/float), never a bool.  This module is pure: it imports
only the standard library and :mod:`app.domain.errors`, so every core package may use it.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable
from typing import Any

from app.domain.errors import ConformaError

__all__ = ["is_finite_number", "require_non_negative", "require_positive"]


def is_finite_number(value: Any) -> bool:
    """True for a finite real number (int, float or NumPy scalar), False for bools."""
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(value))


def require_positive(obj: Any, names: Iterable[str], error_type: type[ConformaError], *,
                     prefix: str = "") -> None:
    """Raise ``error_type`` for the first attribute of ``obj`` in ``names`` that is not a
    finite number > 0."""
    for name in names:
        value = getattr(obj, name)
        if not (is_finite_number(value) and value > 0):
            raise error_type(f"{name} must be a positive finite number", field=prefix + name,
                             value=value)


def require_non_negative(obj: Any, names: Iterable[str], error_type: type[ConformaError], *,
                         prefix: str = "") -> None:
    """Raise ``error_type`` for the first attribute of ``obj`` in ``names`` that is not a
    finite number >= 0."""
    for name in names:
        value = getattr(obj, name)
        if not (is_finite_number(value) and value >= 0):
            raise error_type(f"{name} must be a finite number >= 0", field=prefix + name,
                             value=value)
