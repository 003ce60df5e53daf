"""The shared parameter checks: which values pass, and what the error names."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
import pytest
from annotated_types import Ge, Gt, Le, Lt

from app.domain.checks import (
    declared_bounds,
    is_finite_number,
    require_declared_bounds,
    require_non_negative,
    require_positive,
)
from app.domain.errors import InvalidInput
from app.platform.problems import http_status


class SampleError(InvalidInput):
    pass


@dataclass(frozen=True)
class Sample:
    a: object = 1.0
    b: object = 0.0


@pytest.mark.parametrize("value", [1, 2.5, np.float32(0.5), np.int64(3), 1e300])
def test_finite_numbers_pass(value):
    assert is_finite_number(value)
    require_positive(Sample(a=value), ("a",), SampleError)
    require_non_negative(Sample(b=value), ("b",), SampleError)


@pytest.mark.parametrize("value", [True, False, math.nan, math.inf, -math.inf, "1", None, [1.0]])
def test_non_numbers_bools_and_non_finite_fail(value):
    assert not is_finite_number(value)
    with pytest.raises(SampleError):
        require_non_negative(Sample(b=value), ("b",), SampleError)


def test_positive_rejects_zero_and_names_the_first_bad_field_with_prefix():
    require_non_negative(Sample(), ("a", "b"), SampleError)          # b = 0 is >= 0
    with pytest.raises(SampleError) as info:
        require_positive(Sample(a=-1.0, b=0.0), ("b", "a"), SampleError, prefix="params.")
    err = info.value
    assert (err.field, err.value, err.message) == ("params.b", 0.0,
                                                   "b must be a positive finite number")


def test_non_negative_message_field_and_value():
    with pytest.raises(SampleError) as info:
        require_non_negative(Sample(b=-0.5), ("a", "b"), SampleError)
    err = info.value
    assert (err.field, err.value, err.message) == ("b", -0.5, "b must be a finite number >= 0")
    assert http_status(err)[0] == 422


@dataclass(frozen=True)
class Bounded:
    width_mm: Annotated[float, Gt(0), Le(5)] = 1.0
    count: Annotated[int, Ge(2), Lt(10)] | None = None
    free: float = -1e9


def test_declared_bounds_are_read_from_the_annotations():
    assert declared_bounds(Bounded) == {"width_mm": (("gt", 0), ("le", 5)), "count": (("ge", 2), ("lt", 10))}
    require_declared_bounds(Bounded(width_mm=5, count=9), SampleError)  # the ends the bounds allow
    require_declared_bounds(Bounded(count=None), SampleError)  # an optional field's None passes


@pytest.mark.parametrize(("values", "name", "bad"), [
    ({"width_mm": 0.0}, "width_mm", 0.0), ({"width_mm": 5.001}, "width_mm", 5.001), ({"count": 1}, "count", 1),
    ({"count": 10}, "count", 10), ({"width_mm": math.nan}, "width_mm", None), ({"width_mm": True}, "width_mm", True)])
def test_a_value_outside_its_declared_bounds_is_refused_by_name(values, name, bad):
    with pytest.raises(SampleError) as caught:
        require_declared_bounds(Bounded(**values), SampleError, prefix="params.")
    assert caught.value.field == f"params.{name}"
    if bad is not None:
        assert caught.value.value == bad
