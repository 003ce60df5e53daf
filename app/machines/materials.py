"""Materials: the one place presets and dispense profiles are declared.

A printed-electronics job deposits conductive paste and dielectric ink on a part whose
substrate may itself be printed in plastic.  Each :class:`Material` names what the forms
fill in for it (``params``: job parameter names -> values, e.g. ``mode: dispense`` and the
line width for a paste, nozzle and bed temperatures for a substrate's plastic) and, for what
a dispenser deposits, its :class:`DispenseProfile`: the pressure the dispenser is set to, the
delays after switching it on and off, the standoff and the speed.

A machine holds one dispense profile (``profile.dispense``, ``PATCH /machines/{id}``); a
``print`` job applies its delays (a dwell after each dispenser on/off line,
:mod:`app.gcode.dispense_delays`) and records the whole profile with the print; a print
request may name its own (``params.dispense``).  The standoff and the speed are what the
programs are written with: the console's material picker fills them into the compensate,
circuit and toolpath forms.

The figures are starting points for a new paste on a new machine (a bead test tunes them);
they are not measured properties of any product.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from app.compensation.standoff import DEFAULT_STANDOFF_MM
from app.jobs.form_hints import add_titles_and_units, form

MaterialKind = Literal["conductive", "dielectric", "substrate"]


class DispenseProfile(BaseModel):
    """How a dispenser deposits one material (kPa, ms, mm, mm/min)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra=add_titles_and_units)  # units for forms, from the names

    material: str | None = Field(None, max_length=80, description="the preset this profile came from (a name in "
                                 "GET /materials), or none for a profile of one's own",
                                 json_schema_extra=form(advanced=True))
    pressure_kpa: float = Field(200.0, ge=0, le=1000, allow_inf_nan=False, title="Pressure",
                                description="dispenser pressure, set on the dispenser's controller (the program only "
                                "switches it on and off); recorded with each print")
    on_delay_ms: float = Field(0.0, ge=0, le=10_000, allow_inf_nan=False, title="On delay",
                               description="dwell after the dispenser is switched on, before the head moves")
    off_delay_ms: float = Field(0.0, ge=0, le=10_000, allow_inf_nan=False, title="Off delay",
                                description="dwell after the dispenser is switched off, before the travel")
    standoff_mm: float = Field(DEFAULT_STANDOFF_MM, gt=0, le=50, allow_inf_nan=False, title="Standoff",
                               description="nozzle height above the surface the programs are written for")
    feed_mm_min: float = Field(300.0, gt=0, le=100_000, allow_inf_nan=False, title="Speed",
                               description="dispensing speed the programs are written for")


@dataclass(frozen=True)
class Material:
    """A preset: ``params`` are job parameters by name (a form sets those it has)."""

    name: str
    label: str
    kind: MaterialKind
    description: str
    params: dict[str, Any] = field(default_factory=dict)
    dispense: DispenseProfile | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "label": self.label, "kind": self.kind, "description": self.description,
                "params": dict(self.params),
                "dispense": self.dispense.model_dump() if self.dispense is not None else None}


def _paste(name: str, pressure_kpa: float, on_ms: float, off_ms: float, standoff: float, feed: float,
           line_width: float, nozzle: float) -> tuple[dict[str, Any], DispenseProfile]:
    params = {"mode": "dispense", "line_width_mm": line_width, "nozzle_mm": nozzle, "print_feed_mm_min": feed,
              "perimeter_feed_mm_min": feed, "standoff_mm": standoff, "feed_mm_min": feed}
    return params, DispenseProfile(material=name, pressure_kpa=pressure_kpa, on_delay_ms=on_ms,
                                   off_delay_ms=off_ms, standoff_mm=standoff, feed_mm_min=feed)


def _plastic(nozzle_c: float, bed_c: float) -> dict[str, Any]:
    return {"mode": "extrude", "dialect": "marlin", "nozzle_temp_c": nozzle_c, "bed_temp_c": bed_c,
            "line_width_mm": 0.45, "nozzle_mm": 0.4}


_SILVER = _paste("silver_paste", 250.0, 120.0, 80.0, 0.10, 300.0, 0.25, 0.21)
_CARBON = _paste("carbon_paste", 300.0, 150.0, 100.0, 0.12, 240.0, 0.30, 0.26)
_DIELECTRIC = _paste("dielectric_ink", 150.0, 80.0, 60.0, 0.15, 400.0, 0.40, 0.33)

MATERIALS: tuple[Material, ...] = (
    Material("silver_paste", "Silver paste (conductive)", "conductive",
             "silver-flake paste for traces and pads, 27 G needle (0.21 mm)", *_SILVER),
    Material("carbon_paste", "Carbon paste (conductive, resistive)", "conductive",
             "carbon paste for resistors and heaters, 25 G needle (0.26 mm)", *_CARBON),
    Material("dielectric_ink", "Dielectric ink (insulating)", "dielectric",
             "UV-curing dielectric for crossovers and encapsulation, 23 G needle (0.33 mm)", *_DIELECTRIC),
    Material("pla", "PLA (printed substrate)", "substrate", "a printed substrate's plastic: PLA",
             _plastic(205.0, 60.0)),
    Material("petg", "PETG (printed substrate)", "substrate", "a printed substrate's plastic: PETG",
             _plastic(240.0, 80.0)),
    Material("abs", "ABS (printed substrate)", "substrate", "a printed substrate's plastic: ABS",
             _plastic(245.0, 100.0)),
)
BY_NAME: dict[str, Material] = {m.name: m for m in MATERIALS}
#: what the forms start from: a product for printing electronics starts from a paste, not a plastic
DEFAULT_MATERIAL = "silver_paste"


def material(name: str) -> Material:
    """The preset called ``name``; KeyError if there is none."""
    return BY_NAME[name]
