"""Form hints on the parameter models (app.jobs.form_hints): every field of every kind has a
human title and the unit its name declares; a mode's fields name a real mode field and real
values of it; a choice has alternatives; the toolpath's heaters belong to extrusion only."""

from __future__ import annotations

import re

import pytest

from app.jobs.form_hints import title_of, unit_of
from app.runtime.registry import load_kinds

KINDS = load_kinds()


def _resolved(schema: dict, prop: dict) -> dict:
    branches = [b for b in prop.get("anyOf", [prop]) if b.get("type") != "null"]
    ref = branches[0].get("$ref") if len(branches) == 1 else None
    return schema["$defs"][ref.split("/")[-1]] if ref else branches[0]


def test_names_read_as_words_with_their_units():
    assert (title_of("print_feed_mm_min"), unit_of("print_feed_mm_min")) == ("Print feed", "mm/min")
    assert (title_of("accel_mm_s2"), unit_of("accel_mm_s2")) == ("Acceleration", "mm/s²")
    assert (title_of("slice_job_id"), unit_of("slice_job_id")) == ("Slice job", None)
    assert (title_of("nozzle_temp_c"), unit_of("nozzle_temp_c")) == ("Nozzle temperature", "°C")
    assert (title_of("max_feed_mm_s"), unit_of("max_feed_mm_s")) == ("Maximum feed", "mm/s")
    assert unit_of("pressure_kpa") == "kPa" and unit_of("on_delay_ms") == "ms" and unit_of("infill") is None


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_field_is_titled_and_every_mode_names_real_values(kind):
    schema = KINDS[kind].params.model_json_schema()
    props = schema["properties"]
    choices: dict[str, list[str]] = {}
    for name, prop in props.items():
        title = prop["title"]
        assert title and "_" not in title and not re.search(r"\b(Mm|Id|Ids)\b", title), (name, title)
        if unit_of(name) is not None:
            assert prop["x-unit"] == unit_of(name), name
        for other, allowed in prop.get("x-when", {}).items():
            assert other in props and other != name, (name, other)
            values = _resolved(schema, props[other]).get("enum")
            assert values is not None, f"{name} shows by {other}, which has no fixed values"
            assert all(v is None or v in values for v in allowed), (name, other, allowed, values)
        if "x-choice" in prop:
            choices.setdefault(prop["x-choice"], []).append(name)
    assert all(len(names) >= 2 for names in choices.values()), choices


def test_the_toolpath_heaters_belong_to_extrusion_and_the_dispenser_to_dispensing():
    props = KINDS["toolpath"].params.model_json_schema()["properties"]
    for name in ("nozzle_temp_c", "bed_temp_c", "retract_mm", "filament_mm"):
        assert props[name]["x-when"] == {"mode": ["extrude"]}, name
    assert props["dispense_on"]["x-when"] == {"mode": ["dispense"]} and props["dispense_on"]["x-advanced"]
    assert "x-when" not in props["line_width_mm"] and "x-advanced" not in props["line_width_mm"]
