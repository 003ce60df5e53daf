"""How a kind's parameters read in a form: human labels, units, advanced fields, modes.

Declared once, on the parameter models themselves, and published in their JSON schema
(``GET /api/v1/job-kinds``), so the console has no label or unit table of its own:

* every field of a :class:`~app.runtime.registry.JobParams` model gets a ``title`` made from its
  name without the unit suffix ("line_width_mm" -> "Line width") and an ``x-unit`` read
  from that suffix ("mm"); a field's own ``title`` or :func:`form` ``unit`` wins;
* :func:`form` marks a field ``x-advanced`` (folded in the form), ``x-when`` (shown only
  while another field has one of the given values: a mode's own fields) and ``x-choice``
  (fields of one choice group are alternatives: one trace or several, one is shown at a
  time, labelled by ``x-choice-label``).

Example::

    nozzle_temp_c: float = Field(210.0, json_schema_extra=form(when={"mode": ["extrude"]}, advanced=True))
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel
from pydantic.fields import ComputedFieldInfo, FieldInfo

# suffix -> unit, longest first (so _mm_min is read before _mm)
UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_mm_min", "mm/min"), ("_mm_s2", "mm/s²"), ("_mm_s", "mm/s"), ("_mm3", "mm³"), ("_mm2", "mm²"),
    ("_um", "µm"), ("_mm", "mm"), ("_ms", "ms"), ("_deg", "°"), ("_kpa", "kPa"), ("_c", "°C"),
    ("_s", "s"), ("_h", "h"),
)
# words a label spells out (the rest of a name reads as it is)
WORDS = {"id": "", "ids": "", "xy": "XY", "cl": "CL", "svg": "SVG", "slc": "SLC", "sd": "SD", "temp": "temperature",
         "accel": "acceleration", "min": "minimum", "max": "maximum"}


def unit_of(name: str) -> str | None:
    """The unit a field's name declares by its suffix, or None."""
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return None


def title_of(name: str) -> str:
    """A human label from a field name: the unit suffix and id words dropped, first word capitalised
    ("print_feed_mm_min" -> "Print feed", "slice_job_id" -> "Slice job")."""
    stem = name
    for suffix, _ in UNIT_SUFFIXES:
        if stem.endswith(suffix) and len(stem) > len(suffix):
            stem = stem[: -len(suffix)]
            break
    words = [WORDS.get(w, w) for w in stem.split("_")]
    text = " ".join(w for w in words if w)
    return (text[:1].upper() + text[1:]) if text else name


def field_title(name: str, info: FieldInfo | ComputedFieldInfo) -> str:
    """pydantic's ``field_title_generator`` for job parameters."""
    return title_of(name)


def form(*, unit: str | None = None, advanced: bool = False, when: dict[str, list[Any]] | None = None,
         choice: str | None = None, choice_label: str | None = None) -> dict[str, Any]:
    """A field's form hints, for ``Field(json_schema_extra=form(...))``."""
    out: dict[str, Any] = {}
    if unit is not None:
        out["x-unit"] = unit
    if advanced:
        out["x-advanced"] = True
    if when:
        out["x-when"] = when
    if choice is not None:
        out["x-choice"] = choice
        out["x-choice-label"] = choice_label or ""
    return out


def add_titles_and_units(schema: dict[str, Any], model: type[BaseModel]) -> None:
    """pydantic's model ``json_schema_extra``: each property without a unit gets the one its
    name declares (``x-unit``), and a title if it has none (pydantic gives none to a field
    whose type is a model)."""
    for name, prop in (schema.get("properties") or {}).items():
        if "x-unit" not in prop and (unit := unit_of(name)) is not None:
            prop["x-unit"] = unit
        prop.setdefault("title", title_of(name))


#: the one-trace / several-traces choice the probing and rebuilding kinds share
ONE_TRACE = form(choice="traces", choice_label="one trace")
SEVERAL_TRACES = form(choice="traces", choice_label="several traces, planned together")
