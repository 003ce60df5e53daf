"""The mock printer's physical options beyond the part: tools, the reference artifacts and
the probe's physics parameters, with their URL forms and checks.

* ``MockTool(offset_mm=(x, y, z), outer_diameter_mm=D)``: nozzle ``T<k>`` (k >= 1); its tip
  is at carriage + offset.  URL ``tool<k>=x,y,z,D`` (k = 1..8).
* ``MockPad(centre_mm=(x, y, z), size_mm=s)``: a conductive square block, top face at z,
  sides from the bed up (or ``PAD_DEPTH_MM`` deep when the top is at or below the bed).
  URL ``pad=x,y,z,size``.
* ``MockSphere(centre_mm=(x, y, z), diameter_mm=d)``: a conductive datum sphere on a thin
  stem below it (the stem is not modelled as touchable).  URL ``sphere=x,y,z,diameter``.

Lengths in mm; ``InvalidConfig`` names ``port.<option>`` for URL values and the field
name for values given in code.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import InvalidConfig
from .url_options import url_numbers

#: physics options (floats >= 0) and their upper bounds (mm, mm/min)
PHYSICS_LIMITS = {"stylus_radius_mm": 10.0, "pretravel_mm": 5.0, "pretravel_sd_mm": 1.0,
                  "pretravel_lobing_mm": 1.0, "drift_mm_per_min": 1.0, "touchoff_sd_mm": 1.0}
MAX_TOOLS = 8
COORD_LIMIT_MM = 10_000.0
PAD_DEPTH_MM = 5.0


def _finite_vector(values: tuple[float, ...], field: str, length: int) -> tuple[float, ...]:
    try:
        vector = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise InvalidConfig(f"{field} must be {length} numbers", field=field,
                            value=str(values)[:60]) from None
    if len(vector) != length or not all(math.isfinite(v) and abs(v) <= COORD_LIMIT_MM
                                        for v in vector):
        raise InvalidConfig(f"{field} must be {length} finite numbers within +-{COORD_LIMIT_MM:g} mm",
                            field=field, value=str(values)[:60])
    return vector


def _positive(value: float, field: str, upper: float = 1000.0) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidConfig(f"{field} must be a number", field=field, value=str(value)[:40]) from None
    if not (math.isfinite(number) and 0.0 < number <= upper):
        raise InvalidConfig(f"{field} must be > 0 and <= {upper:g} mm", field=field, value=number)
    return number


@dataclass(frozen=True)
class MockTool:
    """A nozzle: tip = carriage + ``offset_mm``; flat-ended cylinder of ``outer_diameter_mm``."""

    offset_mm: tuple[float, float, float]
    outer_diameter_mm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset_mm", _finite_vector(self.offset_mm, "tools.offset_mm", 3))
        object.__setattr__(self, "outer_diameter_mm",
                           _positive(self.outer_diameter_mm, "tools.outer_diameter_mm", 50.0))


@dataclass(frozen=True)
class MockPad:
    """A conductive square block: top face centred at ``centre_mm``, side ``size_mm``."""

    centre_mm: tuple[float, float, float]
    size_mm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_mm", _finite_vector(self.centre_mm, "pad.centre_mm", 3))
        object.__setattr__(self, "size_mm", _positive(self.size_mm, "pad.size_mm", 500.0))


@dataclass(frozen=True)
class MockSphere:
    """A conductive datum sphere of ``diameter_mm`` centred at ``centre_mm``."""

    centre_mm: tuple[float, float, float]
    diameter_mm: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_mm", _finite_vector(self.centre_mm, "sphere.centre_mm", 3))
        object.__setattr__(self, "diameter_mm", _positive(self.diameter_mm, "sphere.diameter_mm", 500.0))


def check_physics_value(name: str, value: float, field: str) -> float:
    """A physics option: finite, >= 0 and within ``PHYSICS_LIMITS``; else ``InvalidConfig``."""
    upper = PHYSICS_LIMITS[name]
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidConfig(f"{name} must be a number", field=field, value=str(value)[:40]) from None
    if not (math.isfinite(number) and 0.0 <= number <= upper):
        raise InvalidConfig(f"mock option {name} must be within 0..{upper:g}", field=field,
                            value=number)
    return number


def parse_artifact_option(key: str, text: str) -> object | None:
    """``tool<k>``, ``pad`` or ``sphere`` URL values as objects; None for other keys."""
    try:
        if key == "pad":
            x, y, z, size = url_numbers(key, text, 4, "mock")
            return MockPad((x, y, z), size)
        if key == "sphere":
            x, y, z, diameter = url_numbers(key, text, 4, "mock")
            return MockSphere((x, y, z), diameter)
        if tool_number(key) is not None:
            x, y, z, diameter = url_numbers(key, text, 4, "mock")
            return MockTool((x, y, z), diameter)
    except InvalidConfig as exc:
        if exc.field and exc.field.startswith("port."):
            raise
        raise InvalidConfig(f"mock option {key}={text!r}: {exc.message}", field=f"port.{key}",
                            value=text[:60]) from None
    return None


def tool_number(key: str) -> int | None:
    """``"tool3"`` -> 3 (1..MAX_TOOLS); None for any other key."""
    if key.startswith("tool") and key[4:].isdigit() and 1 <= int(key[4:]) <= MAX_TOOLS \
            and str(int(key[4:])) == key[4:]:
        return int(key[4:])
    return None


def merge_tools(tools: tuple[MockTool, ...], given: dict[int, MockTool]) -> tuple[MockTool, ...]:
    """``tools`` with the URL's ``tool<k>`` values set; tool numbers must stay contiguous
    (``tool3`` needs tool1 and tool2, given now or before)."""
    merged = list(tools)
    for number in sorted(given):
        if number <= len(merged):
            merged[number - 1] = given[number]
        elif number == len(merged) + 1:
            merged.append(given[number])
        else:
            missing = ", ".join(f"tool{k}" for k in range(len(merged) + 1, number))
            raise InvalidConfig(f"mock option tool{number} needs {missing} first (tools are T1..Tn)",
                                field=f"port.tool{number}", value=number)
    return tuple(merged)
