"""Job ``reconstruct``: the real trace from measured probe points.

With ``placement`` or ``registration_job_id`` the trace's nominal is mapped into machine
coordinates first (as the probe plan that measured the points did); the reconstruction,
and so the ``compensate`` job that reads it, is then in machine coordinates.  The whole
reconstruction is stored as the artifact ``reconstruction.npz``
(:mod:`app.reconstruction.stored`): ``compensate`` reads it back bit for bit.

Part-level probing: from a probe run of a JOINT plan (``probe_plan`` with ``trace_ids``)
the trace's own points are its range of the run; with ``method: "kriging"`` every other
trace's range joins the posterior as context (the real part's deviation is one field over
the part).  With ``points``, ``context`` gives the other traces' probes explicitly."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from itertools import islice
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from app.calibration import ProbeCalibration
from app.domain.errors import InvalidInput
from app.geometry.placement import Placement
from app.jobs.board_checkpoints import Output, TraceCheckpoints, inputs_sha256, trace_inputs
from app.jobs.core_fields import core_field
from app.jobs.field_runs import run_field
from app.jobs.form_hints import ONE_TRACE, SEVERAL_TRACES, form
from app.jobs.held_reconstructions import HELD
from app.jobs.inputs import (
    check_registration,
    placed_nominal,
    placed_nominals,
    placement_from,
    registration_reference,
)
from app.jobs.params import MAX_FIELD_TRACES, PlacedParams
from app.jobs.probe_correction import refined, run_probe_calibration
from app.jobs.results.models import (
    ProbePlanResult,
    ProbeRunResult,
    ReconstructBoardResult,
    ReconstructResult,
    joint_trace_ranges,
)
from app.jobs.scan_fields import scan_field
from app.platform.models import Trace
from app.probing import PlanParams
from app.reconstruction import (
    PreprocessParams,
    Reconstruction,
    ReconstructionError,
    ReconstructParams,
    preprocess,
    reconstruct,
)
from app.reconstruction.field import trace_reconstruction
from app.reconstruction.field_trust import FieldCheck, trace_bound, trace_bounds, with_bound
from app.reconstruction.stored import reconstruction_npz, stored_name
from app.runtime.context import JobContext
from app.runtime.reads import JobReads
from app.runtime.registry import job_kind

DEGREE = 3
NPZ_MEDIA_TYPE = "application/zip"  # an NPZ is a zip of .npy members

Finite = Annotated[float, Field(allow_inf_nan=False)]
Points = list[Annotated[list[Finite], Field(min_length=3, max_length=3)]]


class ContextTrace(BaseModel):
    """Measured points of another trace of the same part (kriging context)."""

    model_config = ConfigDict(extra="forbid")

    trace_id: str = Field(description="another trace of the same part (not trace_id itself)")
    points: Points = Field(min_length=1, max_length=100_000, description="its measured points [[x, y, z], ...] mm")


class ReconstructJobParams(PlacedParams):
    trace_id: str | None = Field(None, description="the trace to rebuild (or trace_ids)", json_schema_extra=ONE_TRACE)
    trace_ids: list[str] | None = Field(
        None, min_length=1, max_length=MAX_FIELD_TRACES,
        description="board mode (method field, from a field plan's probe run): rebuild these traces in ONE job "
        "from the one fitted field; the result's traces lists each trace's reconstruction in this order",
        json_schema_extra=SEVERAL_TRACES)
    probe_run_job_id: str | None = Field(
        None, description="a succeeded probe_run; when its plan probed several traces (trace_ids), trace_id must "
        "be one of them and its own range of the run is used, with method kriging every other trace's range too "
        "(as context)")
    points: Points | None = Field(
        None, max_length=100_000, description="measured points [[x, y, z], ...] mm, instead of a probe run")
    scan_run_job_id: str | None = Field(
        None, description="a succeeded scan_run (the height sensor) instead of a probe run: method field, every "
        "trace from the field the scan fitted to its samples and checked at its verification touches")
    context: list[ContextTrace] | None = Field(
        None, min_length=1, max_length=199,
        description="kriging with points only: measured points of OTHER traces of the same part (same frame); "
        "they join this trace's in one posterior over the part (pair with a joint kriging plan)",
        json_schema_extra=form(advanced=True, when={"method": ["kriging"]}))
    method: Literal["interpolate", "approximate", "deviation", "kriging", "field"] = Field(
        "interpolate", description="interpolate: the seed's cubic NURBS through the points; approximate: "
        "least squares; deviation: nominal + smoothed deviation (noise-aware); kriging: nominal + the "
        "best estimate of the deviation under the process model below (pair with the kriging planner); "
        "field: nominal + the field fitted once to every station of a field plan's probe run (required "
        "for, and only for, runs of field plans)")
    sigma_mm: float | None = Field(None, ge=0, le=1, description="probe noise (1 sigma); default: the method's own "
                                   "(or the calibration's with sigma_from_calibration)")
    sigma_from_calibration: bool = Field(
        False, description="without sigma_mm, on a calibrated machine's probe run: the probe calibration's measured "
        "scatter of a touch (its residual rms).  Off by default: with method deviation on sparse stations it "
        "smooths the real deviation away (the closed loop measured 1-1.7 um worse, see docs/measured.md)",
        json_schema_extra=form(advanced=True))
    learn_prior: bool = Field(True, description="method field: learn the prior's amplitude, wavelength and noise from "
                              "the stations' touches (type-II maximum likelihood, the plan's prior as start) and "
                              "fit the field with it; false: the plan's prior as stated",
                              json_schema_extra=form(when={"method": ["field"]}))
    deviation_amplitude_mm: float = core_field(PlanParams, "deviation_amplitude_mm",
                                               description="kriging: expected machining error amplitude",
                                               json_schema_extra=form(when={"method": ["kriging"]}))
    deviation_wavelength_mm: float = core_field(PlanParams, "deviation_wavelength_mm",
                                                description="kriging: shortest wavelength of the machining error",
                                                json_schema_extra=form(when={"method": ["kriging"]}))

    @model_validator(mode="after")
    def _one_source(self) -> ReconstructJobParams:
        if sum(x is not None for x in (self.probe_run_job_id, self.points, self.scan_run_job_id)) != 1:
            raise ValueError("give exactly one of probe_run_job_id, points or scan_run_job_id")
        if self.method == "field" and self.probe_run_job_id is None and self.scan_run_job_id is None:
            raise ValueError("method field rebuilds from a field plan's probe run or a scan run: give "
                             "probe_run_job_id or scan_run_job_id")
        if self.scan_run_job_id is not None:
            if self.method != "field":
                raise ValueError("a scan run is rebuilt from its fitted field: method must be field")
            if self.placement is not None or self.registration_job_id is not None:
                raise ValueError("a scan run measures in machine coordinates: leave placement and "
                                 "registration_job_id out")
        if (self.trace_id is None) == (self.trace_ids is None):
            raise ValueError("give exactly one of trace_id or trace_ids")
        if self.trace_ids is not None:
            if self.method != "field":
                raise ValueError("trace_ids (board mode) rebuilds from one fitted field: method must be field")
            if len(set(self.trace_ids)) != len(self.trace_ids):
                raise ValueError("trace_ids lists a trace twice")
        return self

    @property
    def traces(self) -> list[str]:
        """The traces this job rebuilds (one, or the board's)."""
        return list(self.trace_ids) if self.trace_ids is not None else [str(self.trace_id)]


def _references(params: ReconstructJobParams) -> list[tuple[str, str]]:
    refs = [*(("trace", t) for t in params.traces), *registration_reference(params)]
    if params.probe_run_job_id:
        refs.append(("job", params.probe_run_job_id))
    if params.scan_run_job_id:
        refs.append(("job", params.scan_run_job_id))
    refs.extend(("trace", c.trace_id) for c in params.context or ())
    return refs


def _check(params: ReconstructJobParams, reads: JobReads) -> None:
    """Given points must be finite, near the (placed) trace and enough for the method after
    cleaning; context only for kriging, on other traces of the same part; a joint probe run
    must have probed the trace."""
    placement = check_registration(params, reads)
    if params.trace_ids is not None:
        part_id = None
        for index, trace_id in enumerate(params.trace_ids):
            row = reads.trace(trace_id, field=f"params.trace_ids.{index}")
            if part_id is not None and row.part_id != part_id:
                raise InvalidInput(f"trace {trace_id!r} is on part {row.part_id!r}, not on part {part_id!r} of the "
                                   "first trace", field=f"params.trace_ids.{index}", value=trace_id)
            part_id = row.part_id
        if params.probe_run_job_id is not None:
            _check_joint_run(params, reads)
        _check_scan_run(params, reads)
        return
    assert params.trace_id is not None  # the model's rule: trace_id or trace_ids
    trace = reads.trace(params.trace_id, field="params.trace_id")
    _check_scan_run(params, reads)
    if params.probe_run_job_id is not None:
        _check_joint_run(params, reads)
    if params.context is not None:
        _check_context(params, trace, placement, reads)
    if params.points is None:
        return
    clean = preprocess(placed_nominal(trace, placement), params.points, PreprocessParams(), field="params.points")
    if len(clean.s) < DEGREE + 1:
        raise ReconstructionError(
            f"params.points: {len(clean.s)} distinct usable points; a cubic reconstruction needs {DEGREE + 1}",
            field="params.points", value=len(clean.s))


def _check_context(params: ReconstructJobParams, trace: Trace, placement: Placement | None,
                   reads: JobReads) -> None:
    if params.method != "kriging":
        raise InvalidInput(f"context (other traces' probes) is only used by method kriging, not {params.method!r}",
                           field="params.context", value=params.method)
    if params.points is None:
        raise InvalidInput("context goes with points; a joint probe run brings the other traces' probes itself",
                           field="params.context", value=len(params.context or ()))
    seen = {params.trace_id}
    for index, entry in enumerate(params.context or ()):
        field = f"params.context.{index}"
        other = reads.trace(entry.trace_id, field=f"{field}.trace_id")
        if entry.trace_id in seen:
            raise InvalidInput(f"{field}.trace_id: trace {entry.trace_id!r} is trace_id itself or listed twice",
                               field=f"{field}.trace_id", value=entry.trace_id)
        seen.add(entry.trace_id)
        if other.part_id != trace.part_id:
            raise InvalidInput(f"{field}.trace_id: trace {entry.trace_id!r} is on part {other.part_id!r}, not on "
                               f"part {trace.part_id!r} of trace_id", field=f"{field}.trace_id", value=entry.trace_id)
        preprocess(placed_nominal(other, placement), entry.points, PreprocessParams(), field=f"{field}.points")


def _check_scan_run(params: ReconstructJobParams, reads: JobReads) -> None:
    """A scan run must be a succeeded scan_run that scanned every trace asked for (404 / 422)."""
    if params.scan_run_job_id is None:
        return
    job = reads.succeeded_job(params.scan_run_job_id, "scan_run", "params.scan_run_job_id")
    scanned = set((job.params or {}).get("trace_ids") or ())
    for index, trace_id in enumerate(params.traces):
        if trace_id not in scanned:
            field = "params.trace_id" if params.trace_ids is None else f"params.trace_ids.{index}"
            raise InvalidInput(f"trace {trace_id!r} is not one of the traces scanned by scan run {job.id!r}",
                               field=field, value=trace_id)


def _check_joint_run(params: ReconstructJobParams, reads: JobReads) -> None:
    """A run of a joint plan must have probed trace_id (422 ``params.trace_id``); method field
    goes with runs of field plans and only with them (422 ``params.method``)."""
    run = reads.find_job(params.probe_run_job_id)
    plan = reads.find_job((run.params or {}).get("plan_job_id")) if run is not None and run.kind == "probe_run" \
        else None
    if run is None or plan is None:  # nothing to check against
        return
    is_field = bool(ProbePlanResult.of(plan).field)
    if is_field != (params.method == "field"):
        raise InvalidInput(f"probe run {run.id!r} comes from a {'field' if is_field else plan.params.get('method')!r} "
                           f"plan: reconstruct it with method {'field' if is_field else 'other than field'!r}, not "
                           f"{params.method!r}", field="params.method", value=params.method)
    trace_ids = (plan.params or {}).get("trace_ids")
    if is_field and trace_ids is None:
        trace_ids = [plan.params.get("trace_id")]
    if trace_ids is None:
        return
    probed = set(trace_ids)
    for index, trace_id in enumerate(params.traces):
        if trace_id not in probed:
            field = "params.trace_id" if params.trace_ids is None else f"params.trace_ids.{index}"
            raise InvalidInput(f"trace {trace_id!r} is not one of the traces probed by probe run "
                               f"{run.id!r} (plan {plan.id!r})", field=field, value=trace_id)


@job_kind("reconstruct", ReconstructJobParams, references=_references, check=_check)
def run(ctx: JobContext, params: ReconstructJobParams) -> dict:
    """Rebuild the real trace from measured points (outliers rejected, duplicates merged);
    board mode (``trace_ids``): every listed trace from the one fitted field."""
    ctx.progress(0.2, "reconstructing")
    calibrated = calibrated_sigma(ctx, params)
    if params.sigma_mm is not None:
        sigma = {"sigma_mm": params.sigma_mm, "source": "params"}
    elif calibrated is not None:
        sigma = calibrated
        params = params.model_copy(update={"sigma_mm": calibrated["sigma_mm"]})  # what the rebuild uses
    else:
        sigma = {"sigma_mm": None, "source": "default: the method's own"}
    if params.trace_ids is None:
        reconstruction = rebuild(ctx, params)
        _store(ctx, reconstruction, stored_name())
        extra: dict[str, Any] = {}
        if params.method == "field":
            check = _run_field(ctx, params)[0]
            bound = _trace_bound(check, reconstruction.nominal)
            extra = {"bound_mm": bound, "field_check": with_bound(check, [bound]).as_dict()}
        return ReconstructResult.written({**reconstruction.to_result(), "sigma": sigma, **extra})
    rows = _board_rows(ctx, params, sigma)
    check, _, _ = _run_field(ctx, params)
    bounds = [r["bound_mm"] for r in rows if r.get("bound_mm") is not None]
    return ReconstructBoardResult.written({
        "method": "field", "board": True, "traces": rows, "sigma": sigma,
        "field_check": (with_bound(check, bounds) if bounds else check).as_dict(),
        "deviation": {"max_mm": max(r["deviation"]["max_mm"] for r in rows),
                      "rms_mm": max(r["deviation"]["rms_mm"] for r in rows)}})


BOUND_GROUP = 50  # the traces whose bounds are computed in one solve (trace_bounds), as they are rebuilt


def _board_rows(ctx: JobContext, params: ReconstructJobParams, sigma: dict[str, Any]) -> list[dict[str, Any]]:
    """The board result's rows (``params.traces`` order), each trace's reconstruction stored
    as it is made; a trace an earlier attempt of this job finished from the same inputs is
    reused (:mod:`app.jobs.board_checkpoints`), and the field is fitted only if a trace is left."""
    checkpoints = TraceCheckpoints(ctx)
    shared = inputs_sha256({"kind": "reconstruct", "params": params.model_dump(mode="json", exclude={"trace_ids"}),
                            "sigma": sigma})
    parts: dict[str, str] = {}
    keys: dict[str, str] = {}
    done: dict[str, dict[str, Any] | None] = {}
    records = {t.id: t for t in ctx.traces(params.traces, nominals=False)}  # one query, not one per trace
    for trace_id in params.traces:
        trace = records[trace_id]
        if trace.part_id not in parts:
            parts[trace.part_id] = ctx.part(trace.part_id).sha256
        keys[trace_id] = inputs_sha256(shared, trace_inputs(trace, parts[trace.part_id]))
        done[trace_id] = checkpoints.reusable(trace_id, keys[trace_id])
    left = [t for t in params.traces if done[t] is None]
    if checkpoints.reused:
        ctx.progress(0.2, f"{checkpoints.reused}/{len(params.traces)} traces reused from an earlier attempt")
    check = _run_field(ctx, params)[0] if left else None  # once: it reads the run and the plan
    made = zip(left, rebuild_board(ctx, params, [records[t] for t in left]) if left else ())
    while group := list(islice(made, BOUND_GROUP)):
        assert check is not None
        bounds = trace_bounds(check.fit, [rec.nominal for _, rec in group], check.coverage, check.learned,
                              len(params.traces))
        for (trace_id, rec), bound in zip(group, bounds.tolist()):
            name = stored_name(trace_id)
            row = {"trace_id": trace_id, "reconstruction": name, **board_entry(rec), "bound_mm": bound}
            # stored with its group's checkpoint in one commit (a commit per trace cost more than its bound)
            stored = _stored(rec, name)
            checkpoints.add(trace_id, keys[trace_id], [stored], row)
            HELD.hold(rec, stored[1])  # for the compensate job that reads it next, in this process
            done[trace_id] = row
    checkpoints.flush()
    total = len(params.traces)
    ctx.progress(1.0, f"{total}/{total} traces rebuilt{checkpoints.note()}")
    return [entry for t in params.traces if (entry := done[t]) is not None]


def _stored(reconstruction: Reconstruction, name: str) -> Output:
    """``reconstruction`` as the artifact ``name`` to store (``compensate`` reads it back exactly)."""
    return (name, reconstruction_npz(reconstruction), NPZ_MEDIA_TYPE,
            {"format": "npz", "height_model": reconstruction.height_model.kind})


def _store(ctx: JobContext, reconstruction: Reconstruction, name: str) -> str:
    """Store ``reconstruction`` as the artifact ``name`` now; its sha256."""
    return ctx.artifact(*_stored(reconstruction, name))


def calibrated_sigma(ctx: JobContext, params: ReconstructJobParams) -> dict[str, Any] | None:
    """With ``sigma_from_calibration`` and without ``sigma_mm``, a probe run on a calibrated machine
    sets it: the probe qualification's measured scatter of a touch along its move
    (``residual_rms_mm``: pre-travel scatter and noise).  Returns {sigma_mm, source,
    probe_job_id}, or None (not asked, sigma_mm given, points given, or no calibration)."""
    if not params.sigma_from_calibration or params.sigma_mm is not None or params.probe_run_job_id is None:
        return None
    probe_run = ctx.job(str(params.probe_run_job_id), kind="probe_run", field="params.probe_run_job_id")
    stored = ProbeRunResult.of(probe_run).calibration
    scatter = 0.0 if stored is None else ProbeCalibration.from_dict(stored.probe).residual_rms_mm
    if stored is None or not scatter > 0:
        return None
    return {"sigma_mm": scatter, "source": "calibration: the probe qualification's residual rms",
            "probe_job_id": stored.probe_job_id}


def board_entry(rec: Reconstruction) -> dict[str, Any]:
    """One trace of a board reconstruct's result: what a one-trace job's result says, without
    the curve (the trace's reconstruction is stored whole as its own artifact)."""
    return {k: v for k, v in rec.to_result().items() if k != "curve"}


def rebuild_board(ctx: JobContext, params: ReconstructJobParams,
                  traces: list[Trace] | None = None) -> Iterator[Reconstruction]:
    """The reconstructions a board reconstruct makes, one after the other (over the trace
    records ``traces``, default those of ``params.traces``, read in one query): one field fit
    (cached per run, as for one trace) evaluated along each trace (the probe noise as for
    one trace: ``params.sigma_mm``, resolved by :func:`run`)."""
    placement = placement_from(ctx, params)
    check, refinement, plan_traces = _run_field(ctx, params)
    where = {t: i for i, t in enumerate(plan_traces)}
    wanted = ctx.traces(params.traces, nominals=False) if traces is None else traces
    for index, (trace, nominal) in enumerate(zip(wanted, placed_nominals(ctx, wanted, placement))):
        yield _field_trace(check, refinement, nominal, where[trace.id])
        if index % 50 == 49:
            ctx.progress(0.2 + 0.7 * (index + 1) / len(wanted), f"{index + 1}/{len(wanted)} traces rebuilt")


def rebuild(ctx: JobContext, params: ReconstructJobParams) -> Reconstruction:
    """The reconstruction a ``reconstruct`` job with ``params`` makes (stored as the artifact
    ``reconstruction.npz``, which ``compensate`` reads back exactly).

    From a probe run on a calibrated machine with radius correction, the readings are
    turned into surface heights again along the normal of the REAL surface (the nominal's
    tilted by the reconstructed deviation's gradient) and the trace rebuilt, twice
    (:func:`refined`).  The probe noise is ``params.sigma_mm`` as :func:`run` resolved it
    (given, or the calibration's measured scatter with ``sigma_from_calibration``)."""
    assert params.trace_id is not None  # one trace at a time (rebuild_board passes each)
    trace = ctx.trace(params.trace_id)
    placement = placement_from(ctx, params)
    if params.method == "field":
        return _field_rebuild(ctx, params, placed_nominal(trace, placement))
    context: list[tuple[Any, Any]] = []
    rows: list[dict] = []
    calibration = None
    if params.points is not None:
        measured: Any = params.points
        context = [(placed_nominal(ctx.trace(c.trace_id), placement), c.points) for c in params.context or ()]
    else:
        measured, others = run_points(ctx, params)
        if params.method == "kriging":
            context = [(placed_nominal(ctx.trace(t), placement), pts) for t, pts in others.items()]
        calibration, rows = run_calibration(ctx, params)
    nominal = placed_nominal(trace, placement)
    prior = PlanParams(deviation_amplitude_mm=params.deviation_amplitude_mm,
                       deviation_wavelength_mm=params.deviation_wavelength_mm).prior()

    def build(points: Any) -> Reconstruction:
        return reconstruct(nominal, points, params.method, sigma_mm=params.sigma_mm,
                           params=ReconstructParams(prior=prior), context=context)

    result = build(measured)
    if calibration is None:
        return result
    result, refinement = refined(result, rows, calibration, lambda r, xy: r.deviation_gradient_xy(xy), build)
    return replace(result, refinement=refinement)


def run_calibration(ctx: JobContext, params: ReconstructJobParams) -> tuple[Any, list[dict]]:
    """(RunCalibration, this trace's rows of the run) when the run's points carry readings of a
    calibrated probe with radius correction, else (None, [])."""
    probe_run = ctx.job(str(params.probe_run_job_id), kind="probe_run", field="params.probe_run_job_id")
    calibration = run_probe_calibration(probe_run)
    if calibration is None:
        return None, []
    plan = ctx.job(probe_run.params["plan_job_id"], field="params.probe_run_job_id")
    ranges = joint_trace_ranges(plan)
    rows = ProbeRunResult.of(probe_run).rows()
    if ranges is not None:
        assert params.trace_id is not None  # one trace at a time
        lo, hi = ranges[params.trace_id]
        rows = [p for p in rows if lo <= p["index"] < hi]
    return calibration, rows


def run_points(ctx: JobContext, params: ReconstructJobParams) -> tuple[list, dict[str, list]]:
    """Measured points of the probe run: (this trace's, {other trace: its points}); the
    others are empty unless the run's plan probed several traces."""
    probe_run = ctx.job(str(params.probe_run_job_id), kind="probe_run", field="params.probe_run_job_id")
    rows = ProbeRunResult.of(probe_run).rows()
    plan = ctx.job(probe_run.params["plan_job_id"], field="params.probe_run_job_id")
    ranges = joint_trace_ranges(plan)
    if ranges is None:
        return [p["measured"] for p in rows], {}
    if params.trace_id not in ranges:
        raise InvalidInput(f"trace {params.trace_id!r} is not one of the traces probed by probe run "
                           f"{probe_run.id!r} (plan {plan.id!r})", field="params.trace_id", value=params.trace_id)
    by_trace = {t: [p["measured"] for p in rows if lo <= p["index"] < hi] for t, (lo, hi) in ranges.items()}
    own = by_trace.pop(params.trace_id)
    return own, by_trace


def _field_rebuild(ctx: JobContext, params: ReconstructJobParams, nominal: Any) -> Reconstruction:
    """The trace from its run's fitted field (fitted once per run and sigma, cached)."""
    check, refinement, trace_ids = _run_field(ctx, params)
    assert params.trace_id is not None  # one trace at a time
    return _field_trace(check, refinement, nominal, trace_ids.index(params.trace_id))


def _trace_bound(check: FieldCheck, nominal: Any, traces: int = 1) -> float:
    """The bound (mm) over the whole trace under the fitted model, its hyperparameters' own
    uncertainty included, the confidence shared by the run's ``traces`` (:func:`trace_bound`)."""
    return trace_bound(check.fit, nominal, check.coverage, check.learned, traces)


def _field_trace(check: FieldCheck, refinement: Any, nominal: Any, index: int) -> Reconstruction:
    fit = check.fit
    rec = trace_reconstruction(fit, nominal, index, ReconstructParams(prior=fit.posterior.prior))
    return rec if refinement is None else replace(rec, refinement=refinement)


def _run_field(ctx: JobContext, params: ReconstructJobParams) -> tuple[FieldCheck, Any, list[str]]:
    """(checked field, normal-iteration report or None, the plan's trace ids) of the run's
    field (:func:`app.jobs.field_runs.run_field`); every trace of ``params`` must be one of
    the plan's (422 otherwise)."""
    if params.scan_run_job_id is not None:
        return scan_field(ctx, params.scan_run_job_id, params.traces,
                          "params.trace_id" if params.trace_ids is None else "params.trace_ids")
    return run_field(ctx, str(params.probe_run_job_id), params.sigma_mm, params.learn_prior, params.traces,
                     placement_from(ctx, params), method=params.method,
                     trace_field="params.trace_id" if params.trace_ids is None else "params.trace_ids")
