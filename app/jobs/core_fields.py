"""A kind's parameters composed from the core's dataclasses instead of mirroring them.

A core parameter dataclass declares each field once: its type, its default and its bounds
(``typing.Annotated`` with ``annotated_types`` bounds, so the core stays free of pydantic)::

    @dataclass(frozen=True)
    class PlanParams:
        chord_error_mm: Annotated[float, Gt(0), Le(10)] = 0.005

A kind's pydantic model names the field and adds only what the API adds (a description, a
form hint); :func:`core_field` reads the default and the bounds from the core, and
:func:`core_values` builds the core's object from the model by name (no rename, no copy)::

    class ProbePlanParams(JobParams):
        chord_error_mm: float = core_field(PlanParams, "chord_error_mm", description="...")

    PlanParams(**core_values(PlanParams, params, core_only={"end_ratio", ...}))

A name the core does not have fails when the kind's module is imported; a core field the
model lacks (and that the kind does not declare as the core's own) fails when the core's
object is built.
"""

from __future__ import annotations

import dataclasses
import functools
import types
import typing
from collections.abc import Collection
from typing import Any

import annotated_types
from pydantic import BaseModel, Field

#: the ``annotated_types`` bounds a field may declare, and pydantic's ``Field`` keyword of each
_BOUNDS: tuple[tuple[type, str], ...] = (
    (annotated_types.Gt, "gt"), (annotated_types.Ge, "ge"), (annotated_types.Lt, "lt"),
    (annotated_types.Le, "le"), (annotated_types.MinLen, "min_length"), (annotated_types.MaxLen, "max_length"))


@functools.cache
def _fields(core: type) -> dict[str, dataclasses.Field[Any]]:
    return {f.name: f for f in dataclasses.fields(core)}


@functools.cache
def _hints(core: type) -> dict[str, Any]:
    return typing.get_type_hints(core, include_extras=True)


def core_bounds(core: type, name: str) -> dict[str, Any]:
    """The bounds field ``name`` of the dataclass ``core`` declares, as pydantic ``Field``
    keywords (``{"gt": 0, "le": 10}``); those of the non-None member of an optional field."""
    hint = _hints(core)[name]
    members = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    bounds: dict[str, Any] = {}
    for member in members:
        for meta in getattr(member, "__metadata__", ()):
            bounds.update({key: getattr(meta, key) for kind, key in _BOUNDS if isinstance(meta, kind)})
    return bounds


def core_field(core: type, name: str, **extra: Any) -> Any:
    """A pydantic ``Field`` for the dataclass ``core``'s field ``name``: the core's default and
    bounds, plus ``extra`` (``description``, ``json_schema_extra``...).  KeyError for a name
    the core does not have."""
    field = _fields(core)[name]
    if field.default_factory is not dataclasses.MISSING:
        return Field(default_factory=field.default_factory, **core_bounds(core, name), **extra)
    if field.default is dataclasses.MISSING:
        return Field(**core_bounds(core, name), **extra)
    return Field(field.default, **core_bounds(core, name), **extra)


def core_values(core: type, model: BaseModel, core_only: Collection[str] = (), **given: Any) -> dict[str, Any]:
    """The keyword arguments of ``core(...)``: every core field ``model`` has, by name (lists
    as tuples), then ``given`` (the values the kind derives itself).  Each core field comes
    from the model or ``given`` or is named in ``core_only`` (the core's default kept); one
    that is none of them (a name that drifted) is a TypeError naming it."""
    names = type(model).model_fields
    values = {name: getattr(model, name) for name in _fields(core) if name in names and name not in given}
    lost = set(_fields(core)) - set(values) - set(given) - set(core_only)
    if lost:
        raise TypeError(f"{core.__name__} fields {sorted(lost)} are not parameters of {type(model).__name__}")
    return {**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}, **given}
