"""Job ``closed_loop``: (register ->) per trace, plan -> probe -> reconstruct -> compensate (-> print).

``joint_probing``: one plan (``probe_plan`` with ``trace_ids``) and one probe run for all
traces, then per trace reconstruct (from that run) -> compensate (-> print); with the
kriging planner the stations are designed together and, with the kriging reconstruction,
each trace is rebuilt from every trace's probes.

``registration``: a ``register`` child first touches the part's datum features and fits
its placement on the machine; every probe_plan / reconstruct child then gets its
``registration_job_id``, so traces are planned, rebuilt and compensated in machine
coordinates; the result reports the transform and its uncertainty.

Each step is a child job (visible, cancellable, with its own artifacts).  The parent runs
on the ``workflow`` queue and only submits and waits.  Resume: if the parent is retried
(its worker died), succeeded children of the same step and trace are reused, so a
restarted loop continues where it stopped instead of probing again.

A field plan's reconstruction is checked before anything is printed
(:mod:`app.reconstruction.field_trust`: the prior learned from the touches, the verification
points touched after the stations): the result's ``verdict`` states "verified at K points:
max |residual| X um (bound Y um)", the learned prior, every excluded touch and the traces
the correction makes worse at a verification point.  When the check fails (``verdict.
needs_attention``) the loop ends in the state ``needs_attention`` (not ``succeeded``) with
its programs, and ``print`` is refused for every trace (nothing is printed automatically; the operator accepts explicitly
by printing from the machines page, or runs the loop again with ``verdict.suggested_probe``)
and its message says so.

``evaluate`` (mock machines with a true part only): print the nominal program and then
the compensated one on the mock and compare the standoff along what was really deposited
(the mock's deposition log) with the truth — the seed's Table 1, in simulation — and the
top-view (XY) distance of the printed path from the design at the part's true placement.

Probe physics: ``corrections`` switches each calibrated correction (all on by
default; off = left out, for the ablation bench): ``radius`` and ``pretravel`` go to the
probe_run (and reconstruct) children, ``drift`` to the probe_run children and to the print
children (their pad touch before streaming, ``drift_reference``), ``offsets`` to the
compensate children (calibrated nozzle offset, or the profile's nominal).  ``tool`` names
the nozzle the compensate children write for (default: the profile's first).
"""

from __future__ import annotations

import json
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from sqlmodel import Session, select

from app.reference.evaluation import predicted_width, table_row
from app.errors import Cancelled, ConformaError, InvalidInput
from app.jobs.context import JobContext
from app.jobs.params import MAX_FIELD_TRACES, MAX_TRACES, ProbePlanParams, RegisterParams
from app.jobs.machine_jobs import refuse_if_machine_busy
from app.jobs.registry import JobParams, get_kind, job_kind
from app.jobs.loop_results import ClosedLoopResult
from app.jobs.inputs import nominal_of
from app.jobs.results import (CompensateBoardResult, CompensateResult, ProbePlanResult, ReconstructResult,
                              RegisterResult, program_artifacts, reconstruct_rows)
from app.jobs.simulation import evaluate_print, xy_error
from app.reconstruction.field_trust import measured_bound, verification_line
from app.models import Job, Machine, Trace
from app.records import get_or_404

STEPS = ("probe_plan", "probe_run", "reconstruct", "compensate")


class LoopCorrections(BaseModel):
    """The calibrated corrections the loop applies (false: left out, for ablation)."""

    model_config = ConfigDict(extra="forbid")
    radius: bool = Field(True, description="stylus ball radius along the surface normal")
    pretravel: bool = Field(True, description="the probe's calibrated pre-travel")
    drift: bool = Field(True, description="pad re-touches during probe runs and before each print")
    offsets: bool = Field(True, description="the nozzle's calibrated offset (false: the profile's nominal)")


class ClosedLoopParams(JobParams):
    part_id: str
    trace_ids: list[str] = Field(min_length=1, max_length=MAX_FIELD_TRACES)
    machine_id: str
    probe: dict[str, Any] = Field(default_factory=dict,
                                  description="probe_plan parameters (without trace_id); dialect comes from the machine; "
                                  "method defaults to deviation per trace and to field with joint_probing")
    reconstruct_method: Literal["interpolate", "approximate", "deviation", "kriging"] = "deviation"
    sigma_mm: float | None = Field(None, ge=0, le=1, description="probe noise (1 sigma) for the reconstruction")
    chord_error_mm: float = Field(0.002, gt=0, le=1)
    hold_mm: float = Field(0.0, ge=0, le=5)
    print: bool = Field(False, description="print each compensated program on the machine")
    evaluate: bool = Field(False, description="simulation: print nominal and compensated programs on the mock "
                           "and measure the standoff against its true part")
    registration: bool = Field(False, description="register the part on the machine first (datum touches) and "
                               "work in machine coordinates")
    registration_params: dict[str, Any] = Field(default_factory=dict,
                                     description="register parameters (without part_id and machine_id)")
    corrections: LoopCorrections = Field(default_factory=LoopCorrections)
    tool: int | None = Field(None, ge=0, le=8, description="the nozzle the programs are written for (compensate's "
                             "tool; default: the machine profile's first nozzle)")
    joint_probing: bool = Field(False, description="one plan and one probe run for all traces; with the field "
                                "planner (the default here) stations are chosen over the region the traces cover and "
                                "every trace is rebuilt from the one field fitted to the run (reconstruct method field, "
                                "automatic); with kriging the stations are designed per trace together and each "
                                "trace's reconstruction uses every trace's probes (with reconstruct_method kriging); "
                                "trace_ids must be distinct")
    board_jobs: bool = Field(True, description="with joint_probing and a field plan: rebuild and compensate the "
                             "traces in board jobs (one reconstruct and one compensate job per batch of board_batch "
                             "traces, from the one fitted field) instead of two child jobs per trace; each trace's "
                             "programs are then the compensate job's print.<trace_id>.gcode / nominal.<trace_id>.gcode "
                             "(the result's traces name them)")
    sequential: bool = Field(True, description="with joint_probing and the field planner: plan sequentially - a pilot "
                             "plan for the given prior, then rounds that learn the prior from every touch so far and "
                             "add the stations the fitted field still needs (probe_plan fixed_run_job_id), until it "
                             "needs none, touch_budget is reached or max_rounds pass; then the verification points. "
                             "false: one plan for the given prior (+ its verification points)")
    touch_budget: int = Field(2000, ge=1, le=100_000, description="sequential planning: the most touches in all")
    max_rounds: int = Field(4, ge=1, le=10, description="sequential planning: the most rounds after the pilot")
    board_batch: int = Field(250, ge=1, le=MAX_FIELD_TRACES, description="traces per board reconstruct / compensate "
                             "job (a resumed loop reuses every finished batch)")

    @field_validator("probe")
    @classmethod
    def _probe_params(cls, value: dict[str, Any]) -> dict[str, Any]:
        if "trace_id" in value or "trace_ids" in value:
            raise ValueError("probe parameters apply to every trace: leave out trace_id and trace_ids")
        ProbePlanParams.model_validate({**value, "trace_id": "x"})
        return value

    @model_validator(mode="after")
    def _field_is_joint(self) -> "ClosedLoopParams":
        if self.probe.get("method") == "field" and not self.joint_probing:
            raise ValueError("the field planner probes all traces together: set joint_probing")
        if len(self.trace_ids) > MAX_TRACES and not (self.joint_probing and self.probe.get("method", "field") == "field"):
            raise ValueError(f"more than {MAX_TRACES} traces need joint_probing with the field planner")
        return self

    @field_validator("registration_params")
    @classmethod
    def _register_params(cls, value: dict[str, Any]) -> dict[str, Any]:
        if "part_id" in value or "machine_id" in value:
            raise ValueError("register parameters: leave out part_id and machine_id (the loop's are used)")
        RegisterParams.model_validate({**value, "part_id": "x", "machine_id": "x"})
        return value

    @model_validator(mode="after")
    def _one_placement(self) -> "ClosedLoopParams":
        if self.registration and ({"placement", "registration_job_id"} & set(self.probe)):
            raise ValueError("with registration the placement comes from the register step: leave "
                             "placement / registration_job_id out of probe")
        return self


def _check(params: ClosedLoopParams, session: Session) -> None:
    machine = get_or_404(session, Machine, params.machine_id, field="params.machine_id")
    for index, trace_id in enumerate(params.trace_ids):
        trace = session.get(Trace, trace_id)
        if trace is None or trace.part_id != params.part_id:
            raise InvalidInput(f"trace {trace_id!r} is not a trace of part {params.part_id!r}",
                               field=f"params.trace_ids.{index}", value=trace_id)
        if params.joint_probing and trace_id in params.trace_ids[:index]:
            raise InvalidInput(f"trace {trace_id!r} is listed twice; a joint plan probes each trace once",
                               field=f"params.trace_ids.{index}", value=trace_id)
    if params.evaluate and not (machine.mock and machine.mock.get("true_part_id")):
        raise InvalidInput("evaluate needs a mock machine with a true part", field="params.evaluate", value=True)
    refuse_if_machine_busy(params.machine_id, session)


def _references(params: ClosedLoopParams) -> list[tuple[str, str]]:
    return [("part", params.part_id), ("machine", params.machine_id), *(("trace", t) for t in params.trace_ids)]


class _Steps:
    """Runs child jobs, reusing a succeeded child of an earlier attempt of this parent that
    had exactly the same kind and (validated) parameters."""

    def __init__(self, ctx: JobContext) -> None:
        self.ctx = ctx
        with ctx.session() as session:
            done = session.exec(select(Job).where(Job.parent_id == ctx.job_id, Job.status == "succeeded")).all()
        self.reusable = {(j.kind, json.dumps(j.params, sort_keys=True)): j for j in done}

    def run(self, kind: str, params: dict[str, Any], trace_id: str | None) -> Job:
        normalized = get_kind(kind).params.model_validate(params).model_dump(mode="json")
        key = (kind, json.dumps(normalized, sort_keys=True))
        if key in self.reusable:
            return self.reusable[key]
        [job] = self.ctx.wait_for([self.ctx.submit_child(kind, params)])
        if job.status == "cancelled":  # the loop's cancel reached its child first, or a user cancelled the step
            step = kind if trace_id is None else f"{kind} of trace {trace_id}"
            raise Cancelled(f"{step} was cancelled", field="trace_ids", value=trace_id)
        if job.status != "succeeded":
            detail = (job.error or {}).get("detail", job.status)
            if trace_id is None:
                raise ConformaError(f"{kind} {job.status}: {detail}", field=kind, value=job.id)
            raise ConformaError(f"{kind} of trace {trace_id} {job.status}: {detail}", field="trace_ids", value=trace_id)
        return job


@job_kind("closed_loop", ClosedLoopParams, queue="workflow", check=_check, references=_references)
def run(ctx: JobContext, params: ClosedLoopParams) -> dict:
    """Probe, rebuild and compensate every trace on a machine (and print, and evaluate)."""
    machine = ctx.machine(params.machine_id)
    steps = _Steps(ctx)
    per_trace, rows = [], []
    total = len(params.trace_ids)
    placed: dict[str, Any] = {}
    registration = None
    if params.registration:
        ctx.progress(0.0, "registering the part")
        registration = steps.run("register", {**params.registration_params, "part_id": params.part_id,
                                              "machine_id": params.machine_id}, None)
        placed = {"registration_job_id": registration.id}
    shared = None
    if params.joint_probing:
        shared = _plan_and_probe(steps, params, placed, machine.dialect, None, (0.0, f"probing all {total} traces"))
    board = shared is not None and params.board_jobs and bool(ProbePlanResult.of(shared[0]).field)
    batch = params.board_batch if board else 1
    checks: list[dict[str, Any]] = []
    typed = _TypedResults()  # each child's result read once, not once per trace of a board
    for lo in range(0, total, batch):
        if board:
            assert shared is not None
            done = _board_batch(steps, params, placed, shared, params.trace_ids[lo:lo + batch],
                                (lo / total, f"traces {lo + 1}-{min(lo + batch, total)}/{total}: rebuilding and compensating"))
        else:
            done = [_trace_children(steps, params, placed, machine.dialect, shared, lo, total)]
        for index, (trace_id, plan, probe, rebuilt, compensated, deviation, (printed, plain)) in enumerate(done, lo):
            entry = {"trace_id": trace_id, "probe_plan": plan.id, "probe_run": probe.id, "reconstruct": rebuilt.id,
                     "compensate": compensated.id, "probes": typed.probe_count(plan, trace_id),
                     "deviation_max_mm": deviation}
            if board:
                entry |= {"print_artifact": printed, "nominal_artifact": plain}
            check = _field_check(rebuilt, trace_id, entry, plan, typed)
            if check is not None and (not checks or checks[-1] is not check):
                checks.append(check)
            held = any(c["needs_attention"] for c in checks)
            _print_trace(ctx, steps, params, machine, index, entry, rows, hold_print=held)
            per_trace.append(entry)
            ctx.progress((index + 1) / total, f"{index + 1}/{total} traces done")
    result: dict[str, Any] = {"traces": per_trace, "table": rows}
    if checks:
        result["verdict"] = loop_verdict(checks, per_trace, params.print)
        result["verdict"]["retouched"] = [] if shared is None else retouched(shared[0])
        if result["verdict"]["needs_attention"]:
            result["needs_attention"] = True  # the job ends needs_attention, not succeeded
            ctx.progress(1.0, f"{total}/{total} traces done; NEEDS ATTENTION: {result['verdict']['reasons'][0]}"
                         + ("; nothing printed" if params.print else ""))
    if registration is not None:
        result["registration"] = {"job_id": registration.id, **RegisterResult.of(registration).echo()}
    from app.jobs.loop_files import write_loop_files  # the loop's own files, kept out of this module

    result["files"] = write_loop_files(ctx, params.machine_id, result)
    return ClosedLoopResult.written(result)


Done = tuple[str, Job, Job, Job, Job, float, tuple[str, str]]
"""One trace's children: (trace_id, plan, probe run, reconstruct, compensate, deviation max mm,
(print artifact, nominal artifact))."""


def _trace_children(steps: _Steps, params: ClosedLoopParams, placed: dict[str, Any], dialect: str,
                    shared: tuple[Job, Job] | None, index: int, total: int) -> Done:
    """A reconstruct and a compensate child of one trace (and its own plan and run unless shared)."""
    trace_id = params.trace_ids[index]
    plan, probe = shared or _plan_and_probe(steps, params, placed, dialect, trace_id,
                                            ((index + 0.25) / total, f"trace {index + 1}/{total}: probing"))
    prior = {k: params.probe[k] for k in ("deviation_amplitude_mm", "deviation_wavelength_mm") if k in params.probe}
    method = "field" if ProbePlanResult.of(plan).field else params.reconstruct_method
    rebuilt = steps.run("reconstruct", {**_placement_of(params.probe), **placed, **prior,
                                        "trace_id": trace_id, "probe_run_job_id": probe.id,
                                        "method": method, "sigma_mm": params.sigma_mm,
                                        **_corrections_for("reconstruct", params)}, trace_id)
    steps.ctx.progress((index + 0.5) / total, f"trace {index + 1}/{total}: compensating")
    compensated = steps.run("compensate", {"trace_id": trace_id, "reconstruct_job_id": rebuilt.id,
                                           "machine_id": params.machine_id, "chord_error_mm": params.chord_error_mm,
                                           "hold_mm": params.hold_mm, **_tool_of(params)}, trace_id)
    return (trace_id, plan, probe, rebuilt, compensated, ReconstructResult.of(rebuilt).deviation.max_mm,
            program_artifacts(CompensateResult.of(compensated)))


def _board_batch(steps: _Steps, params: ClosedLoopParams, placed: dict[str, Any], shared: tuple[Job, Job],
                 trace_ids: list[str], progress: tuple[float, str]) -> list[Done]:
    """ONE reconstruct and ONE compensate child for a batch of a field plan's traces."""
    plan, probe = shared
    steps.ctx.progress(*progress)
    rebuilt = steps.run("reconstruct", {**_placement_of(params.probe), **placed, "trace_ids": trace_ids,
                                        "probe_run_job_id": probe.id, "method": "field", "sigma_mm": params.sigma_mm,
                                        **_corrections_for("reconstruct", params)}, None)
    compensated = steps.run("compensate", {"trace_ids": trace_ids, "reconstruct_job_id": rebuilt.id,
                                           "machine_id": params.machine_id, "chord_error_mm": params.chord_error_mm,
                                           "hold_mm": params.hold_mm, **_tool_of(params)}, None)
    deviations = {t: row.deviation.max_mm for t, row in reconstruct_rows(rebuilt).items()}
    return [(r.trace_id, plan, probe, rebuilt, compensated, deviations[r.trace_id], program_artifacts(r))
            for r in CompensateBoardResult.of(compensated).traces]


class _TypedResults:
    """The children's results read through their models once per job (a board's children
    serve every trace of their batch: reading them per trace costs traces x rows)."""

    def __init__(self) -> None:
        self._rows: dict[str, dict[str, Any]] = {}
        self._counts: dict[str, tuple[dict[str, int], int]] = {}
        self._indices: dict[str, dict[str, int]] = {}

    def reconstruct_rows(self, rebuilt: Job) -> dict[str, Any]:
        if rebuilt.id not in self._rows:
            self._rows[rebuilt.id] = reconstruct_rows(rebuilt)
        return self._rows[rebuilt.id]

    def probe_count(self, plan: Job, trace_id: str) -> int:
        """How many of the plan's probes are on ``trace_id`` (all of a one-trace plan's; a
        field plan's stations on that trace)."""
        if plan.id not in self._counts:
            result = ProbePlanResult.of(plan)
            counts = {e.trace_id: int(e.stations if e.stations is not None else e.count or 0)
                      for e in reversed(result.traces or ())}  # reversed: a trace's first entry wins
            self._counts[plan.id] = (counts, result.count)
        counts, every = self._counts[plan.id]
        return counts.get(trace_id, every)

    def trace_index(self, plan: Job, trace_id: str) -> int:
        if plan.id not in self._indices:
            ids = plan.params.get("trace_ids") or [plan.params.get("trace_id")]
            self._indices[plan.id] = {t: i for i, t in reversed(list(enumerate(ids)))}
        return self._indices[plan.id][trace_id]


def _field_check(rebuilt: Job, trace_id: str, entry: dict[str, Any], plan: Job,
                 typed: _TypedResults) -> dict[str, Any] | None:
    """A field reconstruct child's check (the same dict object for every trace of one child);
    fills the trace's ``bound_mm`` and ``worse_than_nominal``.  None for other methods."""
    result = rebuilt.result or {}
    check = result.get("field_check")
    if check is None:
        return None
    row = typed.reconstruct_rows(rebuilt)[trace_id]
    entry["bound_mm"] = row.bound_mm
    entry["worse_than_nominal"] = typed.trace_index(plan, trace_id) in check.get("worse_traces", [])
    return check  # type: ignore[no-any-return]


def retouched(plan: Job) -> list[dict[str, Any]]:
    """The touches of a field plan that were touches again of a suspected outlier: station
    (index in the plan's field), xy, trace and ``retouch_of`` (the station touched again)."""
    stations = (ProbePlanResult.of(plan).field or {}).get("stations", [])
    return [{"station": i, "xy": st["xy"], "trace": st["trace"], "retouch_of": int(st["retouch_of"])}
            for i, st in enumerate(stations) if st.get("retouch_of") is not None]


def loop_verdict(checks: list[dict[str, Any]], traces: list[dict[str, Any]], printing: bool) -> dict[str, Any]:
    """The loop's verdict from its field reconstruct children's checks (one per batch, one
    fit): needs_attention if any says so; the bound is the largest trace bound; "verified at
    K points: max |residual| X um (bound Y um)"."""
    first = checks[0]
    reasons = list(dict.fromkeys(r for c in checks for r in c["reasons"]))
    bounds = [t["bound_mm"] for t in traces if t.get("bound_mm") is not None]
    bound = max(bounds) if bounds else first.get("bound_mm")
    points = first.get("verification") or []
    worse = [t["trace_id"] for t in traces if t.get("worse_than_nominal")]
    noise = float(first.get("noise_allowance_mm") or 0.0)  # a touch reads its own noise on top of the bound
    line = verification_line(points, bound, noise)
    said = any("promised for the traces" in r for r in reasons)
    if points and bound is not None and not said and max(abs(p["residual_mm"]) for p in points) > measured_bound(
            bound, noise):
        reasons.append(f"a verification point is off the field by more than the bound {bound * 1000:.1f} um "
                       "promised for the traces")
    learned = first.get("learned")
    suggested = None if learned is None else {
        "deviation_amplitude_mm": learned["amplitude_mm"]["value"],
        "deviation_wavelength_mm": learned["wavelength_mm"]["value"]}
    return {"needs_attention": bool(reasons), "reasons": reasons, "verified": line, "bound_mm": bound,
            "verification": points, "learned": learned, "prior_used": first.get("prior_used"),
            "exclusions": first.get("exclusions", []), "worse_traces": worse,
            "printing_held": bool(reasons) and printing, "suggested_probe": suggested,
            "actions": [] if not reasons else [
                "add stations and refit: run the loop again with probe = suggested_probe (the fitted prior)",
                "or accept explicitly: print the compensate jobs' programs from the machines page"]}


def _print_trace(ctx: JobContext, steps: _Steps, params: ClosedLoopParams, machine: Machine, index: int,
                 entry: dict[str, Any], rows: list[dict[str, Any]], hold_print: bool = False) -> None:
    """Print (or, with ``evaluate``, print both programs of and measure) one compensated trace;
    ``hold_print``: the field check asks for attention, so nothing is printed automatically
    (``evaluate``, a simulation on a mock machine, still measures both programs)."""
    trace_id = entry["trace_id"]
    artifacts = {"nominal.gcode": entry.get("nominal_artifact", "nominal.gcode"),
                 "print.gcode": entry.get("print_artifact", "print.gcode")}
    if params.evaluate:
        trace = ctx.trace(trace_id)
        world = ctx.runtime.machines.world(machine)  # built when the probe run connected
        reports = {}
        for artifact in ("nominal.gcode", "print.gcode"):
            start = len(world.deposition_log)
            steps.run("print", {"machine_id": params.machine_id, "job_id": entry["compensate"],
                                "artifact": artifacts[artifact], "drift_reference": params.corrections.drift}, trace_id)
            reports[artifact] = (evaluate_print(world, start, trace.standoff_mm),
                                 xy_error(world, start, nominal_of(trace).points))
        (before, xy_before), (after, xy_after) = reports["nominal.gcode"], reports["print.gcode"]
        row = table_row(index + 1, before, after, entry["probes"])
        rows.append(row.as_dict() | {"trace_id": trace_id, "name": trace.name,
                                     "xy_max_before_um": round(xy_before.max_mm * 1000, 2),
                                     "xy_max_after_um": round(xy_after.max_mm * 1000, 2)})
        entry["evaluation"] = {"nominal": _report(before, xy_before), "compensated": _report(after, xy_after)}
    elif params.print and not hold_print:
        entry["print"] = steps.run("print", {"machine_id": params.machine_id, "job_id": entry["compensate"],
                                             "artifact": artifacts["print.gcode"],
                                             "drift_reference": params.corrections.drift}, trace_id).id


def _plan_and_probe(steps: _Steps, params: ClosedLoopParams, placed: dict[str, Any], dialect: str,
                    trace_id: str | None, progress: tuple[float, str]) -> tuple[Job, Job]:
    """The probe_plan and probe_run children of one trace, or (``trace_id`` None) of every
    trace of the loop together (joint probing); ``progress`` is reported between them (a
    cancel that came during planning stops the loop before the machine is used)."""
    target: dict[str, Any] = {"trace_ids": params.trace_ids} if trace_id is None else {"trace_id": trace_id}
    default = {} if trace_id is None else {"method": "deviation"}  # joint: the planner's default (field)
    sequential = trace_id is None and params.sequential and params.probe.get("method", "field") == "field"
    pilot = {"verify_count": 0, "pilot": True} if sequential else {}  # coarse; the last round verifies
    base = {**default, **params.probe, **placed, **target, "dialect": dialect}
    plan = steps.run("probe_plan", {**base, **pilot}, trace_id)
    steps.ctx.progress(*progress)
    run = {"machine_id": params.machine_id, **_corrections_for("probe_run", params)}
    probe = steps.run("probe_run", {"plan_job_id": plan.id, **run}, trace_id)
    for round_ in range(params.max_rounds if sequential else 0):
        following = steps.run("probe_plan", {**base, "fixed_run_job_id": probe.id,
                                             "touch_budget": params.touch_budget}, trace_id)
        field = ProbePlanResult.of(following).field or {}
        steps.ctx.progress(progress[0], f"sequential round {round_ + 1}: {field['sequential']['added']} stations "
                           f"added, {ProbePlanResult.of(following).count} touches")
        if ProbePlanResult.of(following).count == 0:
            break
        plan, probe = following, steps.run("probe_run", {"plan_job_id": following.id, **run}, trace_id)
        if field["sequential"]["final"]:
            break
    if trace_id is None and not sequential and ProbePlanResult.of(plan).field:
        # single shot: a touch the fitted field would exclude is touched once more before it may be
        again = steps.run("probe_plan", {**base, "fixed_run_job_id": probe.id, "retouch_only": True}, trace_id)
        if ProbePlanResult.of(again).count:
            steps.ctx.progress(progress[0], f"{ProbePlanResult.of(again).count} suspected outliers touched again")
            plan, probe = again, steps.run("probe_run", {"plan_job_id": again.id, **run}, trace_id)
    return plan, probe


def _corrections_for(kind: str, params: ClosedLoopParams) -> dict[str, Any]:
    """The measuring corrections (radius, pretravel, drift) a child kind takes, as its
    ``corrections`` parameter lists them (nothing for a kind without one)."""
    fields = get_kind(kind).params.model_fields
    if "corrections" not in fields:
        return {}
    wanted = params.corrections.model_dump()
    annotation = fields["corrections"].annotation
    names = getattr(annotation, "model_fields", None)
    return {"corrections": {k: v for k, v in wanted.items() if names is None or k in names}}


def _tool_of(params: ClosedLoopParams) -> dict[str, Any]:
    """compensate's tool and offsets correction (defaults left out: the child's own)."""
    out: dict[str, Any] = {} if params.tool is None else {"tool": params.tool}
    if not params.corrections.offsets:
        out["corrections"] = {"offsets": False}
    return out


def _placement_of(probe: dict[str, Any]) -> dict[str, Any]:
    """An explicit placement among the probe parameters also applies to the reconstruction."""
    return {k: probe[k] for k in ("placement", "registration_job_id") if k in probe}


def _report(report: Any, xy: Any) -> dict[str, float]:
    width = predicted_width(report)
    return {"standoff_error_max_mm": report.max_abs_error_mm, "standoff_error_rms_mm": report.rms_error_mm,
            "width_mean_mm": width.mean_mm, "width_std_mm": width.std_mm, "length_mm": report.length_mm,
            "xy_error_max_mm": xy.max_mm, "xy_error_rms_mm": xy.rms_mm}
