"""Typed results of the job kinds whose results other code reads back (probe_plan,
probe_run, reconstruct, compensate, slice, surface_fit, print, register; five_axis's in
:mod:`app.jobs.results.five_axis`, closed_loop's in
:mod:`app.jobs.results.loop`, the calibrations' in :mod:`app.jobs.results.calibration`,
circuit_program / warp_program / toolpath's in :mod:`app.jobs.results.program`, the jetting
kinds' in :mod:`app.jobs.results.jetting`).

A board job (``reconstruct`` / ``compensate`` with ``trace_ids``) has its own model
(:class:`ReconstructBoardResult`, :class:`CompensateBoardResult`: one row per trace);
:func:`reconstruct_rows` / :func:`compensate_rows` read either form as trace id -> that
trace's typed row.  :class:`ProgramEcho` reads what any job's result echoes about its
programs (dispense lines, a five-axis frame).

A kind writes its result through its model (:meth:`KindResult.written`: a key the model does
not know, or a missing required one, fails the job instead of storing a result nobody can
read) and every reader reads it through the same model (:meth:`KindResult.of`), by
attribute: a renamed field fails loudly in both places instead of reading as an empty
default (``.get("points", [])``).  The stored JSON is what the kind wrote (only the keys it
set are dumped), so the API's results are unchanged.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, ClassVar, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from app.domain.errors import ConformaError
from app.platform.models import Job

R = TypeVar("R", bound="KindResult")
SUMMARY_FIELDS: dict[str, tuple[str, ...]] = {}  # kind -> the fields its results' summaries keep
SUMMARY_MAX_BYTES = 4096  # a declared field larger than this (as JSON) is left out of the summary


class StoredResultError(ConformaError):
    """A stored result that does not match its kind's result model (a defect, not bad input)."""


class KindResult(BaseModel):
    """Base of the result models: unknown keys are errors.  ``summary_fields``: the fields a
    large result's summary keeps (:func:`result_summary`; beside its top-level scalars)."""

    model_config = ConfigDict(extra="forbid")
    kind: ClassVar[str] = ""
    summary_fields: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("summary_fields"):
            SUMMARY_FIELDS[cls.kind] = tuple(dict.fromkeys(SUMMARY_FIELDS.get(cls.kind, ()) + cls.summary_fields))

    @classmethod
    def of(cls: type[R], job: Job) -> R:
        """The stored result of ``job`` (a job of this model's kind) read through the model."""
        return cls._read(job.id, job.kind, job.result)

    @classmethod
    def of_record(cls: type[R], record: Mapping[str, Any]) -> R:
        """The same for a job as a plain dict (``Job.model_dump``: ``id``, ``kind``, ``result``)."""
        return cls._read(str(record.get("id")), str(record.get("kind")), record.get("result"))

    @classmethod
    def _read(cls: type[R], job_id: str, kind: str, result: Mapping[str, Any] | None) -> R:
        if kind != cls.kind:
            raise StoredResultError(f"job {job_id!r} is a {kind} job, not a {cls.kind} job", field="kind",
                                    value=kind)
        try:
            return cls.model_validate(result or {})
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise StoredResultError(f"the result of {cls.kind} job {job_id!r} does not match {cls.__name__}: "
                                    f"{where}: {first['msg']}", field=f"result.{where}", value=job_id) from None

    @classmethod
    def written(cls, result: dict[str, Any]) -> dict[str, Any]:
        """``result`` checked against the model; what is stored (the keys given, as given)."""
        return cls.model_validate(result).model_dump(exclude_unset=True)


# probe_plan -------------------------------------------------------------------------------
class PlannedTrace(BaseModel):
    """One trace of a part-level plan: its range ``[first, first + count)`` of the points (joint
    plans), or its ``index`` and ``stations`` (field plans)."""

    model_config = ConfigDict(extra="forbid")
    trace_id: str
    trace_length_mm: float
    predicted_sd_mm: float | None = None
    first: int | None = None
    count: int | None = None
    s_mm: list[float] | None = None
    index: int | None = None
    stations: int | None = None


class ProbePlanResult(KindResult):
    kind: ClassVar[str] = "probe_plan"
    count: int
    method: str
    points: list[list[float]]
    s_mm: list[float | None]
    records: list[dict[str, Any]]
    program: dict[str, Any]
    spacing_mm: float | None = None
    trace_length_mm: float | None = None
    placement: dict[str, Any] | None = None
    point_count: dict[str, Any] | None = None
    traces: list[PlannedTrace] | None = None
    field: dict[str, Any] | None = None

    def joint_ranges(self) -> dict[str, tuple[int, int]] | None:
        """Each trace's range of the points of a joint (not field) plan, else None."""
        if self.field or self.traces is None:
            return None
        return {t.trace_id: (int(t.first or 0), int(t.first or 0) + int(t.count or 0)) for t in self.traces}


# probe_run --------------------------------------------------------------------------------
class ProbedPoint(BaseModel):
    """One probed station: ``measured`` is the surface point (corrected on a calibrated probe)."""

    model_config = ConfigDict(extra="forbid")
    index: int
    nominal: list[float]
    measured: list[float]
    deviation_mm: float
    reading: list[float] | None = None
    t_s: float | None = None
    normal: list[float] | None = None
    drift_mm: float | None = None
    correction_mm: float | None = None


class ProbeRunCalibration(BaseModel):
    """The probe calibration a probe run applied: its job, the corrections (radius,
    pre-travel, drift) and the calibration itself (``ProbeCalibration.to_dict``), the pad
    re-touches (``drift``: times_s, pad_z_mm, interval_s) when drift was tracked."""

    model_config = ConfigDict(extra="forbid")
    probe_job_id: str | None = None
    corrections: dict[str, Any]
    probe: dict[str, Any]
    drift: dict[str, Any] | None = None


class ProbeStats(BaseModel):
    """The run's measured - nominal heights: count, largest |d|, mean and rms (mm)."""

    model_config = ConfigDict(extra="forbid")
    count: int
    max_abs_mm: float
    mean_mm: float
    rms_mm: float


class ProbeRunResult(KindResult):
    kind: ClassVar[str] = "probe_run"
    points: list[ProbedPoint]
    resumes: int
    stats: ProbeStats
    calibration: ProbeRunCalibration | None = None

    def rows(self) -> list[dict[str, Any]]:
        """The points as stored (dicts), for the probe corrections."""
        return [p.model_dump(exclude_unset=True) for p in self.points]


# reconstruct ------------------------------------------------------------------------------
class DeviationSummary(BaseModel):
    model_config = ConfigDict(extra="forbid")
    max_mm: float
    rms_mm: float
    samples: list[list[float]]


class ReconstructResult(KindResult):
    kind: ClassVar[str] = "reconstruct"
    method: str
    curve: dict[str, Any]
    deviation: DeviationSummary
    points_used: int
    outliers: list[int]
    merged_duplicates: int
    normal_iteration: dict[str, Any] | None = None
    sigma: dict[str, Any] | None = None  # the probe noise used: given, the calibration's, or the default
    field_check: dict[str, Any] | None = None  # method field: learned prior, verification, verdict
    bound_mm: float | None = None  # method field: coverage x the trace's largest posterior sd (fitted model)


class BoardDeviation(BaseModel):
    """The largest of a board's traces' deviation figures."""

    model_config = ConfigDict(extra="forbid")
    max_mm: float
    rms_mm: float


class ReconstructBoardTrace(BaseModel):
    """One trace of a board reconstruct: what a one-trace job's result says but the curve
    (its reconstruction is stored as the artifact ``reconstruction``, see
    :func:`app.reconstruction.stored.stored_name`)."""

    model_config = ConfigDict(extra="forbid")
    trace_id: str
    reconstruction: str
    method: str
    deviation: DeviationSummary
    points_used: int
    outliers: list[int]
    merged_duplicates: int
    normal_iteration: dict[str, Any] | None = None
    bound_mm: float | None = None  # coverage x the trace's largest posterior sd under the fitted model


class ReconstructBoardResult(KindResult):
    """A board reconstruct job (``trace_ids``): every trace from one fitted field."""

    kind: ClassVar[str] = "reconstruct"
    method: str
    board: Literal[True]
    traces: list[ReconstructBoardTrace]
    deviation: BoardDeviation
    sigma: dict[str, Any] | None = None
    field_check: dict[str, Any] | None = None  # learned prior, verification, verdict (app.reconstruction.field_trust)


def is_board(job: Job) -> bool:
    """A board job: ``reconstruct`` / ``compensate`` with ``trace_ids``."""
    return bool((job.params or {}).get("trace_ids"))


def joint_trace_ranges(plan: Job) -> dict[str, tuple[int, int]] | None:
    """{trace id: [first, stop) point indices} of a joint probe plan (``probe_plan`` with
    ``trace_ids``; the same indices hold in its probe runs); None for a one-trace plan and
    for a field plan (its stations are shared by the traces, see ``reconstruct`` method field)."""
    if not (plan.params or {}).get("trace_ids"):
        return None
    return ProbePlanResult.of(plan).joint_ranges()


def reconstruct_rows(job: Job) -> dict[str, ReconstructResult | ReconstructBoardTrace]:
    """trace id -> the typed result of that trace, of a one-trace or a board reconstruct job."""
    if is_board(job):
        return {row.trace_id: row for row in ReconstructBoardResult.of(job).traces}
    return {str(job.params.get("trace_id")): ReconstructResult.of(job)}


# compensate -------------------------------------------------------------------------------
class CompensateResult(KindResult):
    kind: ClassVar[str] = "compensate"
    dispense_on: str
    dispense_off: str
    segments: int
    length_mm: float
    max_chord_error_mm: float
    standoff_mm: float
    method: str
    span_mm: list[float]
    trace_extent_mm: list[float]
    extension_mm: list[float]
    nominal_segments: int
    slope: dict[str, Any] | None
    points: list[list[float]]
    tool: dict[str, Any]
    warnings: list[str]
    clearance: dict[str, Any] | None = None
    placement: dict[str, Any] | None = None


class CompensateBoardTrace(CompensateResult):
    """One trace of a board compensate job: a one-trace job's figures, and the names of its
    programs (``print.<trace_id>.gcode`` / ``nominal.<trace_id>.gcode``)."""

    trace_id: str
    print_artifact: str
    nominal_artifact: str


class CompensateBoardResult(KindResult):
    """A board compensate job (``trace_ids``): each trace's programs from its stored reconstruction."""

    kind: ClassVar[str] = "compensate"
    board: Literal[True]
    traces: list[CompensateBoardTrace]


def compensate_rows(job: Job) -> dict[str, CompensateResult]:
    """trace id -> the typed result of that trace, of a one-trace or a board compensate job
    (a board row is a :class:`CompensateBoardTrace`, which names the trace's programs)."""
    if is_board(job):
        return {row.trace_id: row for row in CompensateBoardResult.of(job).traces}
    return {str(job.params.get("trace_id")): CompensateResult.of(job)}


def program_artifacts(row: CompensateResult) -> tuple[str, str]:
    """(print, nominal) artifact names of one trace's row of a compensate job."""
    if isinstance(row, CompensateBoardTrace):
        return row.print_artifact, row.nominal_artifact
    return "print.gcode", "nominal.gcode"


# slice ------------------------------------------------------------------------------------
class SliceResult(KindResult):
    """A slice job: the layers' figures (``layers``: one row per layer) and where the part lies
    in its own frame (``bounds`` [[x, y, z] min, max] mm)."""

    kind: ClassVar[str] = "slice"
    mode: str
    layer_count: int
    vertices: int | None = None  # contour vertices over all layers (the toolpath's cost model)
    contour_mm: float | None = None  # contour length over all layers, mm (the same)
    z_min: float
    z_max: float
    bounds: list[list[float]]
    frame: str
    volume_mm3: float
    repairs: list[Any]
    notes: list[str]
    beam: dict[str, Any]
    slc: dict[str, Any]
    svg: dict[str, Any]
    layers: list[dict[str, Any]]


# surface_fit ------------------------------------------------------------------------------
class ProbeGrid(BaseModel):
    """The planned probe grid of a surface fit: ``points`` [x, y, z or None] mm."""

    model_config = ConfigDict(extra="forbid")
    shape: list[int]
    x: list[float]
    y: list[float]
    index: list[Any]
    points: list[list[float | None]]


class SurfaceFitResult(KindResult):
    """A surface_fit job: ``surface`` is :meth:`app.geometry.nurbs_surface.NurbsSurface.to_dict`."""

    kind: ClassVar[str] = "surface_fit"
    source: str
    surface: dict[str, Any]
    residual: dict[str, Any]
    probe_grid: ProbeGrid
    removed_points: list[list[float]]
    filled_holes: int
    method: str
    smoothing: str
    control_net: list[int]
    region: dict[str, Any]


# print ------------------------------------------------------------------------------------
class PrintResult(KindResult):
    """A print job: how much of the program ran (``executed`` of ``total`` commands)."""

    kind: ClassVar[str] = "print"
    executed: int
    total: int
    start_line: int
    resumes: int
    resume_preamble: list[str]
    elapsed_s: float
    program: dict[str, Any]
    link: dict[str, Any]
    resume_location: dict[str, Any] | None = None
    source_program: dict[str, Any] | None = None
    drift: dict[str, Any] | None = None
    # the dispense profile applied (app.machines.materials), with its dwell counts
    dispense: dict[str, Any] | None = None


# register ---------------------------------------------------------------------------------
class RegisterResult(KindResult):
    """A register job: the fitted ``placement`` (:meth:`app.geometry.placement.Placement.to_dict`
    form: dx, dy, dz mm, rz_deg, pivot), its ``std`` / ``covariance`` (mm and degrees), the
    parameters the touches could not see (``unobservable``), each face fit's rms (mm), the
    touches, the datum plan and the probe calibration applied (when the machine has one)."""

    kind: ClassVar[str] = "register"
    placement: dict[str, Any]
    std: dict[str, float]
    covariance: dict[str, Any]
    unobservable: list[str]
    rms_mm: dict[str, float]
    probe_count: int
    touches: list[dict[str, Any]]
    mode: str
    plan: dict[str, Any]
    calibration: dict[str, Any] | None = None

    def echo(self) -> dict[str, Any]:
        """What a closed loop echoes of its registration: placement, std, covariance,
        unobservable, probe_count (as stored)."""
        return self.model_dump(include={"placement", "std", "covariance", "unobservable", "probe_count"})


# any job's program echo -------------------------------------------------------------------
class ProgramEcho(BaseModel):
    """What a job's result may echo about the programs it wrote (any kind; every field
    optional): the dispense on/off lines, and a five-axis program's frame (``pivot``
    [x0, y0, z0] mm, ``post``).  Keys of the kind's own result are ignored."""

    model_config = ConfigDict(extra="ignore")
    dispense_on: str | None = None
    dispense_off: str | None = None
    pivot: list[float] | None = None
    post: str | None = None

    @classmethod
    def of_any(cls, job: Job) -> ProgramEcho:
        """The echo in ``job``'s result (all None without a result); a present field of the
        wrong type is a :class:`StoredResultError` naming ``result.<field>``."""
        try:
            return cls.model_validate(job.result or {})
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise StoredResultError(f"the result of {job.kind} job {job.id!r} echoes a bad {where}: {first['msg']}",
                                    field=f"result.{where}", value=job.id) from None


# any job's summary ------------------------------------------------------------------------
def result_summary(kind: str, result: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """What a job's record shows in place of a large result: its top-level scalars, the
    fields its kind declares (``KindResult.summary_fields``, each at most SUMMARY_MAX_BYTES
    of JSON), and ``<key>_count`` for each top-level list (its length)."""
    if result is None:
        return None
    out: dict[str, Any] = {}
    for key, value in result.items():
        if value is None or isinstance(value, (bool, int, float, str)):
            out[key] = value
        elif isinstance(value, list) and f"{key}_count" not in result:
            out[f"{key}_count"] = len(value)
    for key in SUMMARY_FIELDS.get(kind, ()):
        if key in result and len(json.dumps(result[key])) <= SUMMARY_MAX_BYTES:
            out[key] = result[key]
    return out
