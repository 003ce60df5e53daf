"""Parameter models that more than one job kind uses (a kind never imports another kind).

* :class:`PlacementParams` / :class:`PlacedParams`: a rigid placement of the part on the
  machine, explicit or a ``register`` job's (probe_plan and reconstruct take it; closed_loop
  passes it on);
* :class:`RegisterParams`: the ``register`` kind's parameters (closed_loop validates its
  ``registration_params`` with them);
* :class:`ProbePlanParams`: the ``probe_plan`` kind's parameters (closed_loop validates its
  ``probe`` with them);
* :data:`DispensingDialect`: the dialects a print program can target without a machine
  (the writer's :data:`~app.gcode.writer.DISPENSING_DIALECTS`, a subset of its one list);
* :data:`StandoffMm` and :func:`standoff_of`: a job's standoff and how it falls back to the
  trace's, then to the one default.

Loading what the parameters point to (placements, nominals, succeeded jobs) is in
:mod:`app.jobs.inputs`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from app.compensation.standoff import DEFAULT_STANDOFF_MM
from app.gcode.writer import DEFAULT_PROBING_DIALECT, DISPENSING_DIALECTS, DialectName, ProbeStyle
from app.geometry.placement import Placement
from app.jobs.core_fields import core_bounds, core_field, core_values
from app.jobs.form_hints import ONE_TRACE as _ONE
from app.jobs.form_hints import SEVERAL_TRACES as _SEVERAL
from app.jobs.form_hints import form
from app.probing import PlanParams
from app.probing.program import ProbeProgramParams
from app.registration.datum_plan import DatumProbeParams
from app.runtime.registry import JobParams

Finite = Annotated[float, Field(allow_inf_nan=False, ge=-10_000, le=10_000)]
#: a job's standoff (nozzle tip above the surface), mm; None in a job: :func:`standoff_of`
StandoffMm = Annotated[float, Field(gt=0, le=50)]

if TYPE_CHECKING:  # mypy checks against the one list; pydantic and the OpenAPI schema see the subset
    DispensingDialect = DialectName
else:
    DispensingDialect = Literal[DISPENSING_DIALECTS]


def standoff_of(job_mm: float | None, trace_mm: float | None) -> float:
    """The standoff a program is written for, mm: the job's, else the trace's (or its circuit
    import's), else :data:`~app.compensation.standoff.DEFAULT_STANDOFF_MM`."""
    if job_mm is not None:
        return float(job_mm)
    return float(trace_mm) if trace_mm is not None else DEFAULT_STANDOFF_MM

_MORE = form(advanced=True)  # a folded field (app.jobs.form_hints)
_DEVIATION = form(when={"method": ["deviation", "kriging", "field"]})
MAX_TRACES = 200
#: traces of one field-planned loop: a whole circuit import (its traces and the probe rings
#: of its pads and areas: at most the import's MAX_SHAPES, app.circuits.budget)
MAX_FIELD_TRACES = 20_000


class PlacementParams(BaseModel):
    """A rigid placement of the part on the machine (what a ``register`` job reports)."""

    model_config = ConfigDict(extra="forbid")

    dx: float = Field(0.0, ge=-1000, le=1000, description="x translation, mm")
    dy: float = Field(0.0, ge=-1000, le=1000, description="y translation, mm")
    dz: float = Field(0.0, ge=-1000, le=1000, description="z translation, mm")
    rz_deg: float = Field(0.0, ge=-180, le=180, description="rotation about the vertical axis through pivot, degrees")
    pivot: list[Finite] = Field(default_factory=lambda: [0.0, 0.0], min_length=2, max_length=2,
                                description="rotation axis (machine x, y) mm")

    def to_placement(self) -> Placement:
        return Placement.from_deg(self.dx, self.dy, self.dz, self.rz_deg, (self.pivot[0], self.pivot[1]))


class PlacedParams(JobParams):
    """Parameters of jobs that can work in machine coordinates (a placed trace)."""

    placement: PlacementParams | None = Field(
        None, description="map the trace into machine coordinates with this placement before use")
    registration_job_id: str | None = Field(
        None, description="a succeeded register job whose placement maps the trace into machine coordinates")

    @model_validator(mode="after")
    def _one_placement(self) -> PlacedParams:
        if self.placement is not None and self.registration_job_id is not None:
            raise ValueError("give at most one of placement or registration_job_id")
        return self


class RegisterParams(JobParams):
    part_id: str
    machine_id: str
    mode: Literal["edges", "z_only"] = Field(
        "edges", description="edges: side faces found by -Z bisection across each wall + top heights "
        "(dx, dy, rz from planar walls); z_only: -Z touches on the top only")
    count: int | None = Field(None, ge=1, le=50, description="datum features to touch (default 6 edges, 8 z_only)")
    sigma_mm: float = core_field(DatumProbeParams, "sigma_mm", description="probe repeatability (1 sigma)")
    search_mm: float = core_field(DatumProbeParams, "search_mm", description="edge search half-width: the largest "
                                  "placement error the edge search finds; below margin_mm")
    resolution_mm: float = core_field(DatumProbeParams, "resolution_mm",
                                      description="edge bisection stops at this bracket")
    tip_radius_mm: float | None = Field(None, **core_bounds(DatumProbeParams, "tip_radius_mm"),
                                        description="probe ball radius (the top edge is caught early); default: "
                                        "the machine's calibrated ball radius, else 0")
    margin_mm: float = Field(2.0, gt=0, le=50, description="datum touches keep this far from face edges")
    pivot_xy: list[Finite] = Field(default_factory=lambda: [0.0, 0.0], min_length=2, max_length=2,
                                   description="rotation axis of the reported placement (machine x, y) mm")
    clearance_mm: float = Field(2.0, gt=0, le=100, description="travel height above the part's top",
                                json_schema_extra=_MORE)
    overtravel_mm: float = Field(1.0, gt=0, le=50, description="probe down to this far below the part's bottom",
                                 json_schema_extra=_MORE)
    probe_feed_mm_min: float | None = Field(None, gt=0, le=10_000, description="default: the machine profile's",
                                            json_schema_extra=_MORE)
    seed: int = Field(0, ge=0, le=2**31 - 1, description="seed of the candidate sampling (plans are deterministic)")

    @model_validator(mode="after")
    def _search_within_margin(self) -> RegisterParams:
        if self.mode == "edges" and self.search_mm >= self.margin_mm:
            raise ValueError("search_mm must be below margin_mm (the edge search starts over the part)")
        return self

    def probe_params(self, tip_radius_mm: float) -> DatumProbeParams:
        """How the datum touches are made: this job's fields by name; ``tip_radius_mm``: the
        job's, else the machine's calibrated ball radius, else 0 (mm)."""
        return DatumProbeParams(**core_values(DatumProbeParams, self, {"max_touches_per_edge"},
                                              tip_radius_mm=tip_radius_mm))


#: the planners' and the probe program's fields a probe_plan job keeps at the core's defaults
PLAN_CORE_ONLY = frozenset({"end_ratio", "min_count", "peak_factor", "placement_xy_mm", "placement_z_mm",
                            "placement_rz_deg", "tilt_rad"})
PROGRAM_CORE_ONLY = frozenset({"sample_mm", "decimals"})


class ProbePlanParams(PlacedParams):
    trace_id: str | None = Field(None, description="the trace to probe (give this or trace_ids)",
                                 json_schema_extra=_ONE)
    trace_ids: list[str] | None = Field(
        None, min_length=1, max_length=MAX_FIELD_TRACES,
        description="part-level probing (instead of trace_id): several distinct traces of ONE part, probed by "
        "one program in this order; with the kriging planner their stations are designed together (fewer "
        "probes per trace when each trace is rebuilt from every trace's probes, see reconstruct). The result's "
        "traces list each trace's range [first, first + count) in points / records", json_schema_extra=_SEVERAL)
    method: Literal["adaptive", "uniform", "deviation", "kriging", "field"] | None = Field(
        None, description="adaptive (default with trace_id): the seed's chord-height rule; uniform: even arc "
        "length; deviation: spacing from the expected deviation of the real part from CAD; kriging: stations "
        "that minimise the largest predicted error of the deviation (machining error + placement), per trace "
        "or jointly; field (default with trace_ids): stations over the whole region the traces cover, one "
        "field for any number of traces, the fewest probes for a board")
    stations: Literal["on_traces", "anywhere_on_top"] = Field(
        "on_traces", description="field planner: stations on the traces, or anywhere on the part's top the probe "
        "reaches (within a quarter wavelength of a trace)", json_schema_extra=form(when={"method": ["field"]}))
    chord_error_mm: float = core_field(PlanParams, "chord_error_mm",
                                       json_schema_extra=form(when={"method": [None, "adaptive"]}))
    count: int | None = core_field(PlanParams, "count", description="probe count (uniform/deviation; per trace "
                                   "with trace_ids; field: for the whole board)")
    coverage: float = core_field(PlanParams, "coverage", description="kriging/field: coverage x largest predicted "
                                 "sd <= target_error_mm", json_schema_extra=form(when={"method": ["kriging", "field"]}))
    verify_count: int = Field(5, ge=0, le=100, description="field planner: verification points touched after the "
                              "stations where the traces' posterior is least certain; never used in the fit, they "
                              "check it (reconstruct's field_check)",
                              json_schema_extra=form(when={"method": ["field", None]}))
    fixed_run_job_id: str | None = Field(None, description="field planner, sequential round: a probe run of an "
                                         "earlier field plan of the same traces; the prior is learned from every "
                                         "station touched so far and the plan adds only the stations the fitted "
                                         "field still needs for the run's bound to meet the target (none: only the "
                                         "verification points)",
                                         json_schema_extra=form(advanced=True, when={"method": ["field", None]}))
    pilot: bool = Field(False, description="field planner, the pilot of a sequential plan: a coarse plan for twice "
                        "deviation_wavelength_mm (the rounds add what the learned prior asks for)",
                        json_schema_extra=form(advanced=True, when={"method": ["field", None]}))
    retouch_only: bool = Field(False, description="with fixed_run_job_id: touch again only the touches the field "
                               "fitted to that run would exclude as outliers (once each), add no stations and keep "
                               "the run's verification points (a single-shot plan's second run; none: no touches)",
                               json_schema_extra=form(advanced=True, when={"method": ["field", None]}))
    last_round: bool = Field(False, description="with fixed_run_job_id: the last sequential round the loop allows: "
                             "adds no stations, only the verification points (stopped: rounds, unless the run's "
                             "bound already holds)",
                             json_schema_extra=form(advanced=True, when={"method": ["field", None]}))
    touch_budget: int | None = Field(None, ge=1, le=100_000, description="sequential round: the most touches in all "
                                     "(stations so far + added + verification); a round that would pass it adds "
                                     "no stations and says so",
                                     json_schema_extra=form(advanced=True, when={"method": ["field", None]}))
    exchange: bool = core_field(PlanParams, "exchange", description="field planner, automatic count: refine the "
                                "design by exchange moves (2-11 % fewer stations, about twice the planning time, "
                                "less slack when a touch is rejected as an outlier)",
                                json_schema_extra=form(advanced=True, when={"method": ["field", None]}))
    capability_k: float | None = core_field(PlanParams, "capability_k", json_schema_extra=_MORE,
                                            description="point-count formula: process capability K")
    confidence: float | None = core_field(PlanParams, "confidence", json_schema_extra=_MORE,
                                          description="point-count formula: confidence gamma")
    cl_tolerance_mm: float = core_field(PlanParams, "cl_tolerance_mm", json_schema_extra=_MORE)
    deviation_amplitude_mm: float = core_field(PlanParams, "deviation_amplitude_mm", json_schema_extra=_DEVIATION)
    deviation_wavelength_mm: float = core_field(PlanParams, "deviation_wavelength_mm", json_schema_extra=_DEVIATION)
    target_error_mm: float = core_field(PlanParams, "target_error_mm",
                                        json_schema_extra=form(when={"method": ["kriging", "field", None]}))
    probe_sigma_mm: float = core_field(PlanParams, "probe_sigma_mm", json_schema_extra=_MORE)
    clearance_mm: float = core_field(ProbeProgramParams, "clearance_mm", json_schema_extra=_MORE)
    approach_mm: float = core_field(ProbeProgramParams, "approach_mm", json_schema_extra=_MORE)
    overtravel_mm: float = core_field(ProbeProgramParams, "overtravel_mm", json_schema_extra=_MORE)
    probe_feed_mm_min: float = core_field(ProbeProgramParams, "probe_feed_mm_min", json_schema_extra=_MORE)
    dialect: DialectName = Field(DEFAULT_PROBING_DIALECT, description="G-code dialect of the probe program")
    probe_style: ProbeStyle | None = core_field(ProbeProgramParams, "probe_style", json_schema_extra=_MORE,
                                                description="default: G38.2 on grbl, G30 on Marlin")

    @model_validator(mode="after")
    def _both_or_neither(self) -> ProbePlanParams:
        if (self.capability_k is None) != (self.confidence is None):
            raise ValueError("capability_k and confidence go together (the published point-count formula)")
        if (self.trace_id is None) == (self.trace_ids is None):
            raise ValueError("give exactly one of trace_id or trace_ids")
        if self.trace_ids is not None and len(self.trace_ids) > MAX_TRACES and self.planner != "field":
            raise ValueError(f"more than {MAX_TRACES} traces are planned by the field planner only")
        return self

    def plan_params(self) -> PlanParams:
        """The planners' parameters: every one this job has, by name."""
        return PlanParams(**core_values(PlanParams, self, PLAN_CORE_ONLY))

    def program_params(self, part_max_z_mm: float) -> ProbeProgramParams:
        """The probe program's parameters; ``part_max_z_mm``: the (placed) part's top, mm."""
        return ProbeProgramParams(**core_values(ProbeProgramParams, self, PROGRAM_CORE_ONLY,
                                                part_max_z_mm=part_max_z_mm))

    @property
    def planner(self) -> str:
        """The method given, else field for part-level plans (trace_ids), adaptive for one trace."""
        return self.method or ("field" if self.trace_ids is not None else "adaptive")
