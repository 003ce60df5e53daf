"""Typed results of the program-writing kinds ``circuit_program``, ``warp_program`` and
``toolpath`` (``print``'s is :class:`app.jobs.results.models.PrintResult`).

Written by the kinds through :meth:`app.jobs.results.models.KindResult.written` and read back through
:meth:`~app.jobs.results.models.KindResult.of` (see :mod:`app.jobs.results.models`).  Lengths in mm, times in s.
"""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict
from pydantic.dataclasses import dataclass

from app.circuits.warp import WarpFigures
from app.jobs.results.models import KindResult
from app.slicing.toolpath import PathCounts


# circuit_program --------------------------------------------------------------------------
class CircuitProgramResult(KindResult):
    """A circuit_program job: strokes written (``fill_strokes`` of them pad / area fills), the
    import's trace count, the pad probe rings used and the stations of the deviation field
    (a field: the stations it is fitted from, every round's once, verification points apart),
    the named nets the short check went through (``nets_checked``), the source's connected
    pieces the open check went through (``connections_checked``), the travel (mm) in the chosen
    and in the input order, the order ([input index, reversed] per stroke) and the dispense codes;
    ``surface``: the measured surface every printed point follows (``model`` field or stations,
    the field's ``verified`` line and ``needs_attention``) and what each printed item (by name:
    kind, points, worst posterior ``sd_mm``, its ``bound_mm`` = coverage x sd, the nozzle's
    smallest ``clearance_min_mm`` over the surface, its ``standoff_mm``) and the whole program
    predict (:meth:`app.circuits.surface.PrintedPoints.as_dict`); ``loop``: the closed loop it
    came from (``job_id``, ``status``, ``accepted_unverified``: it ended needs_attention and the
    request accepted it, with the verdict's ``reasons``)."""

    kind: ClassVar[str] = "circuit_program"
    strokes: int
    traces: int
    fill_strokes: int
    pad_probe_traces: list[str]
    stations: int
    nets_checked: int = 0
    connections_checked: int = 0
    travel_mm: float
    travel_input_order_mm: float
    order: list[tuple[int, bool]]
    dispense_on: str
    dispense_off: str
    surface: dict[str, Any] | None = None
    loop: dict[str, Any] | None = None


# warp_program -----------------------------------------------------------------------------
class FixedSplit(BaseModel):
    """The fixed-length split reported beside the warp: its length, pieces and worst error (mm)."""

    model_config = ConfigDict(extra="forbid")
    split_mm: float
    pieces: int
    max_error_mm: float


class WarpHeightModel(BaseModel):
    """The height model the warp used, chosen by cross-validation on the surface's points: its
    kind, the scheme, the prediction error (rms, max mm: the model's own uncertainty beside the
    chord bound, which holds against the model), every model's rms compared, the kriging
    candidate's parameters and exact leave-one-out error (scattered points), and the kriging
    model's largest posterior sd over the measured region when it was chosen (mm)."""

    model_config = ConfigDict(extra="forbid")
    kind: str
    cv: str
    cv_rms_mm: float | None
    cv_max_mm: float | None
    alternatives: dict[str, float | None]
    kriging: dict[str, float] | None = None
    posterior_sd_max_mm: float | None = None


class WarpProgramResult(KindResult, WarpFigures):
    """A warp_program job: the warp's figures (the core's :class:`~app.circuits.warp.WarpFigures`:
    lines in and out, printing moves, emitted pieces, the largest chord bound against the height
    model and the travel height, mm) and beside them ``model_error_mm``, how far the height
    model itself may be from the part (its cross-validated max error, mm; None when it cannot
    be measured): the chord bound is conditional on the model.  The height model and how it
    was chosen, and the fixed split compared."""

    kind: ClassVar[str] = "warp_program"
    model_error_mm: float | None = None
    height_model: WarpHeightModel | None = None
    fixed_split: FixedSplit


# toolpath ---------------------------------------------------------------------------------
class ToolpathEstimator(BaseModel):
    """Which time estimator ran, the planner's own description and the machine limits used."""

    model_config = ConfigDict(extra="forbid")
    name: str
    description: str
    limits: dict[str, Any]


class VolumeEcho(BaseModel):
    """The machine's travel limits used ([min, max] mm per axis) and where they came from."""

    model_config = ConfigDict(extra="forbid")
    x: list[float]
    y: list[float]
    z: list[float]
    source: str


class ToolpathPlacement(BaseModel):
    """Where the part went on the bed: the placement asked (``xy``, ``offset_mm``,
    ``drop_to_bed``), the shift applied (mm), the machine volume and a note."""

    model_config = ConfigDict(extra="forbid")
    xy: str
    offset_mm: list[float]
    drop_to_bed: bool
    shift_mm: list[float]
    volume_mm: VolumeEcho
    note: str


@dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class ToolpathLayer(PathCounts):
    """One layer's figures: its moves (the core's :class:`~app.slicing.toolpath.PathCounts`:
    path and travel mm, turns, jumps), z and thickness (mm), the estimated and the planner's
    time (s) and its pieces."""

    index: int
    z: float
    thickness: float
    time_s: float
    planner_time_s: float
    pieces: int


class ToolpathResult(KindResult, PathCounts):
    """A toolpath job: the totals of its moves (the core's :class:`~app.slicing.toolpath.PathCounts`),
    the estimated and the planner's time (s), the program's G-code summary (``program``:
    :func:`app.jobs.gcode_meta.gcode_meta`), the placement and each layer."""

    kind: ClassVar[str] = "toolpath"
    time_s: float
    planner_time_s: float
    estimator: ToolpathEstimator
    pattern: str
    layer_count: int
    program: dict[str, Any]
    placement: ToolpathPlacement
    layers: list[ToolpathLayer]
