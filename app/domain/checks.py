"""Shared parameter checks for the frozen parameter dataclasses of the pure core.

Each check reads the named attributes of a parameter object in order and raises the
caller's error type for the first bad one, naming it: ``field`` is ``prefix + name``
(e.g. ``"params.feed_mm_min"``) and ``value`` the offending value.  A number here is a
real number (Python or NumPy int/float), never a bool.  This module is pure: it imports
only the standard library and :mod:`app.domain.errors`, so every core package may use it.

:func:`require_declared_bounds` checks the bounds a parameter dataclass declares in its
annotations (``typing.Annotated[float, annotated_types.Gt(0), annotated_types.Le(10)]``,
the bounds a kind's parameter model reads as well), so the core refuses what the API
refuses; it reads the bound objects by their ``gt`` / ``ge`` / ``lt`` / ``le`` attributes.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import operator
import types
import typing
from collections.abc import Callable, Iterable
from typing import Any

from app.domain.errors import ConformaError

__all__ = ["declared_bounds", "is_finite_number", "require_declared_bounds", "require_non_negative",
           "require_positive"]


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


#: a declared bound's attribute, its comparison (value OP bound must hold) and its words
_BOUNDS: tuple[tuple[str, Callable[[Any, Any], bool], str], ...] = (
    ("gt", operator.gt, ">"), ("ge", operator.ge, ">="), ("lt", operator.lt, "<"), ("le", operator.le, "<="))


@functools.cache
def declared_bounds(cls: type) -> dict[str, tuple[tuple[str, Any], ...]]:
    """The numeric bounds each field of the dataclass ``cls`` declares in its annotation
    (those of the non-None member of an optional field): ``{name: (("gt", 0), ("le", 10))}``,
    fields without bounds left out."""
    hints = typing.get_type_hints(cls, include_extras=True)
    found: dict[str, tuple[tuple[str, Any], ...]] = {}
    for field in dataclasses.fields(cls):
        hint = hints[field.name]
        union = typing.get_origin(hint) in (typing.Union, types.UnionType)
        members = typing.get_args(hint) if union else (hint,)
        bounds = tuple((key, getattr(meta, key)) for member in members
                       for meta in getattr(member, "__metadata__", ())
                       for key, _, _ in _BOUNDS if getattr(meta, key, None) is not None)
        if bounds:
            found[field.name] = bounds
    return found


def require_declared_bounds(obj: Any, error_type: type[ConformaError], *, prefix: str = "") -> None:
    """Raise ``error_type`` for the first field of the dataclass ``obj`` outside the bounds its
    annotation declares (see :func:`declared_bounds`), naming it and its value; None passes
    (an optional field left out), any other value must be a finite number."""
    compare = {key: (test, words) for key, test, words in _BOUNDS}
    for name, bounds in declared_bounds(obj.__class__).items():
        value = getattr(obj, name)
        if value is None:
            continue
        if not is_finite_number(value):
            raise error_type(f"{name} must be a finite number", field=prefix + name, value=value)
        for key, bound in bounds:
            test, words = compare[key]
            if not test(value, bound):
                raise error_type(f"{name} must be {words} {bound:g}, got {value:g}", field=prefix + name,
                                 value=value)
