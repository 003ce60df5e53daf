"""Job ``closed_loop``: (register ->) per trace, plan -> probe -> reconstruct -> compensate (-> print).

``joint_probing``: one plan (``probe_plan`` with ``trace_ids``) and one probe run for all
traces, then per trace reconstruct (from that run) -> compensate (-> print); with the
kriging planner the stations are designed together and, with the kriging reconstruction,
each trace is rebuilt from every trace's probes.

``registration``: a ``register`` child first touches the part's datum features and fits
its placement on the machine; every probe_plan / reconstruct child then gets its
``registration_job_id``, so traces are planned, rebuilt and compensated in machine
coordinates; the result reports the transform and its uncertainty.

``measuring: scan``: ONE ``scan_run`` child measures every trace with the laser height
sensor (its ``scan`` parameters; the calibration defaults to the machine's stored one, a
machine without one is refused at submission), touching where the sensor dropped out and at
its verification points; then board ``reconstruct`` children rebuild the traces from the
scan's checked field (``scan_run_job_id``) and the same compensate / verdict / print steps
follow: a scan whose verification fails ends ``needs_attention`` like a touch loop.  No
``plan`` pause (the scan plans and scans in one machine job), no registration (the scan
measures in machine coordinates), no added stations (run again with a finer ``spacing_mm``).

Each step is a child job (visible, cancellable, with its own artifacts).  The parent runs
on the ``workflow`` queue and only submits and waits (:mod:`app.jobs.loop_steps`).  Its
phases: every plan, then every probe run, then every trace rebuilt and compensated, then
the verdict, then the prints.  Resume: when the parent runs again (its worker died, an
operator resumed or continued it), succeeded children of the same step and trace are
reused, so it continues where it stopped instead of probing again.

Pause points (``pause_at``: ``plan``, ``probed``, ``verified``, ``print``; none by default,
all from the console): the loop stops there as a ``waiting`` job, holding no worker, until
an operator continues, accepts, adds stations or abandons it (:mod:`app.jobs.loop_gates`).
With ``verified`` a failed verification waits there instead of ending ``needs_attention``.

Trace ends beyond their own probes (a trace that starts on a pad): held at the nearest
probe's deviation within ``end_hold_max_mm`` (the row's ``held_ends_mm`` says so), beyond
it the loop stops naming the trace (:func:`app.jobs.loop_steps.end_hold`).

A field plan's reconstruction is checked before anything is printed
(:mod:`app.reconstruction.field_trust`: the prior learned from the touches, the verification
points touched after the stations): the result's ``verdict`` states "verified at K points:
max |residual| X um (bound Y um)", the learned prior, every excluded touch and the traces
the correction makes worse at a verification point.  When the check fails (``verdict.
needs_attention``) the loop ends in the state ``needs_attention`` (not ``succeeded``) with
its programs, and ``print`` is refused for every trace (nothing is printed automatically; the operator accepts
explicitly by printing from the machines page, or runs the loop again with ``verdict.suggested_probe``)
and its message says so.  An operator may then accept it (``POST /jobs/{id}/accept``: it
runs again, reuses every child, prints and ends ``succeeded`` with ``verdict.accepted``) or
add stations (``POST /jobs/{id}/add-stations``: one more round planned from the run so far).

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

import time
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from app.compensation.standoff import CompensationParams
from app.domain.errors import InvalidInput
from app.jobs.core_fields import core_field
from app.jobs.loop_files import write_loop_files
from app.jobs.loop_gates import Gates, PausePoint
from app.jobs.loop_steps import (
    Steps,
    TypedResults,
    board_batch,
    is_sequential,
    measured_by,
    more_rounds,
    plan_params,
    print_trace,
    probe_rings,
    run_params,
    scan_params,
    scanned_summary,
    trace_children,
)
from app.jobs.params import MAX_FIELD_TRACES, MAX_TRACES, ProbePlanParams, RegisterParams
from app.jobs.results.loop import ClosedLoopResult
from app.jobs.results.models import ProbePlanResult, RegisterResult
from app.jobs.sensor_calibration import scan_calibration
from app.jobs.sensor_runs import require_sensor_port
from app.platform.models import Job
from app.reconstruction.field_trust import measured_bound, verification_line
from app.runtime.context import JobContext
from app.runtime.machine_queue import refuse_if_machine_busy
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

STEPS = ("probe_plan", "probe_run", "reconstruct", "compensate")
PROGRESS_EVERY_S = 0.5  # the per-trace phase reports its progress at most this often (thousands of traces)


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
                                  description="probe_plan parameters (without trace_id); dialect comes from the "
                                  "machine; method defaults to deviation per trace and to field with joint_probing")
    reconstruct_method: Literal["interpolate", "approximate", "deviation", "kriging"] = "deviation"
    sigma_mm: float | None = Field(None, ge=0, le=1, description="probe noise (1 sigma) for the reconstruction")
    chord_error_mm: float = core_field(CompensationParams, "chord_error_mm")  # the compensate steps'
    hold_mm: float = core_field(CompensationParams, "hold_mm")
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
                                "every trace is rebuilt from the one field fitted to the run (reconstruct method "
                                "field, automatic); with kriging the stations are designed per trace together and each "
                                "trace's reconstruction uses every trace's probes (with reconstruct_method kriging); "
                                "trace_ids must be distinct")
    board_jobs: bool = Field(True, description="with joint_probing and a field plan: rebuild and compensate the "
                             "traces in board jobs (one reconstruct and one compensate job per batch of board_batch "
                             "traces, from the one fitted field) instead of two child jobs per trace; each trace's "
                             "programs are then the compensate job's print.<trace_id>.gcode / nominal.<trace_id>.gcode "
                             "(the result's traces name them)")
    sequential: bool = Field(True, description="with joint_probing and the field planner: plan sequentially - a pilot "
                             "plan for the given prior, then rounds that learn the prior from every touch so far and "
                             "add the stations the fitted field still needs (probe_plan fixed_run_job_id), until the "
                             "run's bound as the verdict computes it meets the target (within its 25 %), touch_budget "
                             "is reached or max_rounds pass; then the verification points. "
                             "false: one plan for the given prior (+ its verification points)")
    touch_budget: int = Field(2000, ge=1, le=100_000, description="sequential planning: the most touches in all")
    max_rounds: int = Field(6, ge=1, le=10, description="sequential planning: the most rounds after the pilot "
                            "(the last adds no stations: it touches the verification points)")
    pause_at: list[PausePoint] = Field(default_factory=list, max_length=4, description="where the loop waits "
                                       "for an operator (plan, probed, verified, print): the job is then waiting "
                                       "until POST /jobs/{id}/continue, accept, add-stations or abandon; none by "
                                       "default (the console asks for all)")
    end_hold_max_mm: float = Field(0.5, ge=0, le=5, description="a trace's end beyond its own probes (a trace "
                                   "starting on a pad): up to this gap the deviation at the nearest probe is held "
                                   "(the trace's held_ends_mm), beyond it the loop stops naming the trace")
    measuring: Literal["touch", "scan"] = Field("touch", description="touch: probe_plan + probe_run children; scan: "
                                                "ONE scan_run child (the laser height sensor, verification touches "
                                                "included), every trace rebuilt from its field in board jobs")
    scan: dict[str, Any] = Field(default_factory=dict, description="measuring scan: scan_run parameters (without "
                                 "machine_id and trace_ids); sensor_port is required except on a linuxcnc:// machine "
                                 "(its controller samples the sensor), calibration defaults to the machine's stored "
                                 "one (the newest calibrate_sensor job)")
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
    def _field_is_joint(self) -> ClosedLoopParams:
        if self.probe.get("method") == "field" and not self.joint_probing:
            raise ValueError("the field planner probes all traces together: set joint_probing")
        if len(self.trace_ids) > MAX_TRACES and not (self.joint_probing
                                                     and self.probe.get("method", "field") == "field"):
            raise ValueError(f"more than {MAX_TRACES} traces need joint_probing with the field planner")
        return self

    @model_validator(mode="after")
    def _scan_params(self) -> ClosedLoopParams:
        if self.measuring == "touch":
            if self.scan:
                raise ValueError("scan parameters are for measuring scan")
            return self
        if "machine_id" in self.scan or "trace_ids" in self.scan:
            raise ValueError("scan parameters: leave out machine_id and trace_ids (the loop's are used)")
        if self.registration or self.joint_probing or self.probe:
            raise ValueError("measuring scan scans in machine coordinates with its own plan: leave registration, "
                             "joint_probing and probe out")
        if len(set(self.trace_ids)) != len(self.trace_ids):
            raise ValueError("measuring scan: trace_ids lists a trace twice")
        scan_params({"machine_id": "x", "trace_ids": ["x"], **self.scan})
        return self

    @field_validator("registration_params")
    @classmethod
    def _register_params(cls, value: dict[str, Any]) -> dict[str, Any]:
        if "part_id" in value or "machine_id" in value:
            raise ValueError("register parameters: leave out part_id and machine_id (the loop's are used)")
        RegisterParams.model_validate({**value, "part_id": "x", "machine_id": "x"})
        return value

    @model_validator(mode="after")
    def _one_placement(self) -> ClosedLoopParams:
        if self.registration and ({"placement", "registration_job_id"} & set(self.probe)):
            raise ValueError("with registration the placement comes from the register step: leave "
                             "placement / registration_job_id out of probe")
        return self


def _check(params: ClosedLoopParams, reads: JobReads) -> None:
    machine = reads.machine(params.machine_id, field="params.machine_id")
    seen: set[str] = set()
    for index, trace_id in enumerate(params.trace_ids):
        trace = reads.find_trace(trace_id)  # read with the others at submission (Runtime.submit)
        if trace is None or trace.part_id != params.part_id:
            raise InvalidInput(f"trace {trace_id!r} is not a trace of part {params.part_id!r}",
                               field=f"params.trace_ids.{index}", value=trace_id)
        if params.joint_probing and trace_id in seen:
            raise InvalidInput(f"trace {trace_id!r} is listed twice; a joint plan probes each trace once",
                               field=f"params.trace_ids.{index}", value=trace_id)
        seen.add(trace_id)
    if params.evaluate and not (machine.mock and machine.mock.get("true_part_id")):
        raise InvalidInput("evaluate needs a mock machine with a true part", field="params.evaluate", value=True)
    if params.measuring == "scan":
        require_sensor_port(params.machine_id, machine.port, params.scan.get("sensor_port"),
                            "params.scan.sensor_port")
        scan_calibration(reads, params.machine_id, params.scan.get("calibration"), field="params.scan.calibration")
    refuse_if_machine_busy(params.machine_id, reads)


def _references(params: ClosedLoopParams) -> list[tuple[str, str]]:
    return [("part", params.part_id), ("machine", params.machine_id), *(("trace", t) for t in params.trace_ids)]


@job_kind("closed_loop", ClosedLoopParams, queue="workflow", check=_check, references=_references)
def run(ctx: JobContext, params: ClosedLoopParams) -> dict:
    """Probe, rebuild and compensate every trace on a machine (and print, and evaluate),
    pausing at ``pause_at`` (:mod:`app.jobs.loop_gates`)."""
    machine = ctx.machine(params.machine_id)
    steps, gates = Steps(ctx), Gates(ctx, list(params.pause_at))
    total = len(params.trace_ids)
    placed: dict[str, Any] = {}
    registration = None
    if params.registration:
        ctx.progress(0.0, "registering the part")
        registration = steps.run("register", {**params.registration_params, "part_id": params.part_id,
                                              "machine_id": params.machine_id}, None)
        placed = {"registration_job_id": registration.id}
    shared: tuple[Job, Job] | None  # the joint (plan, run) of a field plan or a scan
    runs: list[tuple[Job, Job]]
    if params.measuring == "scan":
        ctx.progress(0.0, f"scanning all {total} traces")
        scanned = steps.run("scan_run", {**params.scan, "machine_id": params.machine_id,
                                         "trace_ids": params.trace_ids}, None)
        shared, runs, rounds = (scanned, scanned), [], 0
        gates.gate("probed", scanned_summary(scanned, total))
    else:
        shared, runs, rounds = _probe(steps, gates, params, placed, machine.dialect)
        gates.gate("probed", _probed_summary(runs, total), round_=rounds)
    board = shared is not None and (params.measuring == "scan" or (
        params.board_jobs and bool(ProbePlanResult.of(shared[0]).field)))
    batch = params.board_batch if board else 1
    per_trace: list[dict[str, Any]] = []
    checks: list[dict[str, Any]] = []
    typed = TypedResults()  # each child's result read once, not once per trace of a board
    for lo in range(0, total, batch):
        ctx.progress(0.4 + 0.4 * lo / total, f"traces {lo + 1}-{min(lo + batch, total)}/{total}: rebuilding "
                     "and compensating")
        held: list[float] | None = None
        if board:
            assert shared is not None
            done = board_batch(steps, params, placed, shared, params.trace_ids[lo:lo + batch])
        else:
            plan, probe = shared or runs[lo]
            one, held = trace_children(steps, params, placed, plan, probe, params.trace_ids[lo])
            done = [one]
        for trace_id, plan, probe, rebuilt, compensated, deviation, (printed, plain) in done:
            entry = {"trace_id": trace_id, **measured_by(plan, probe), "reconstruct": rebuilt.id,
                     "compensate": compensated.id, "probes": typed.probe_count(plan, trace_id),
                     "deviation_max_mm": deviation}
            if board:
                entry |= {"print_artifact": printed, "nominal_artifact": plain}
            if held is not None:
                entry["held_ends_mm"] = held
            check = _field_check(rebuilt, trace_id, entry, plan, typed)
            if check is not None and (not checks or checks[-1] is not check):
                checks.append(check)
            per_trace.append(entry)
    result: dict[str, Any] = {"traces": per_trace, "table": []}
    attention = False
    if checks:
        result["verdict"] = loop_verdict(checks, per_trace, params.print)
        result["verdict"]["retouched"] = [] if shared is None else retouched(shared[0])
        if params.measuring == "scan" and result["verdict"]["actions"]:
            result["verdict"]["actions"] = [
                "run the loop again with a finer scan.spacing_mm or more scan.gap_touches (stations are added to "
                "touch fields only)", result["verdict"]["actions"][-1]]
        attention = bool(result["verdict"]["needs_attention"])
    gates.gate("verified", _verified_summary(result, per_trace), round_=rounds, attention=attention)
    accepted = gates.decisions.accepted
    if accepted is not None and attention:
        result["verdict"] |= {"accepted": accepted, "printing_held": False}
    hold = attention and accepted is None
    rings = probe_rings(ctx, params.trace_ids) if params.print or params.evaluate else set()
    to_print = [entry for entry in per_trace if entry["trace_id"] not in rings]
    if (params.print or params.evaluate) and not hold:
        gates.gate("print", _print_summary(to_print, params), round_=rounds)
    reported = time.monotonic()
    for index, entry in enumerate(per_trace):
        if entry["trace_id"] in rings:
            entry["role"] = "pad_probe"  # a pad's probe ring: probed and rebuilt, never printed
        else:
            print_trace(ctx, steps, params, machine, index, entry, result["table"], hold_print=hold)
        if index + 1 == total or time.monotonic() - reported >= PROGRESS_EVERY_S:  # not one write per trace
            ctx.progress(0.8 + 0.2 * (index + 1) / total, f"{index + 1}/{total} traces done")
            reported = time.monotonic()
        else:
            ctx.check_cancelled()
    if hold:
        result["needs_attention"] = True  # the job ends needs_attention, not succeeded
        ctx.progress(1.0, f"{total}/{total} traces done; NEEDS ATTENTION: {result['verdict']['reasons'][0]}"
                     + ("; nothing printed" if params.print else ""))
    if registration is not None:
        result["registration"] = {"job_id": registration.id, **RegisterResult.of(registration).echo()}
    result["files"] = write_loop_files(ctx, params.machine_id, result)
    return ClosedLoopResult.written(result)


def _probe(steps: Steps, gates: Gates, params: ClosedLoopParams, placed: dict[str, Any],
           dialect: str) -> tuple[tuple[Job, Job] | None, list[tuple[Job, Job]], int]:
    """Every plan, then (after the ``plan`` pause) every probe run: (the joint (plan, run) or
    None, each (plan, run) made, the round of stations added on request)."""
    total = len(params.trace_ids)
    if not params.joint_probing:
        plans = [steps.run("probe_plan", plan_params(params, placed, dialect, t), t) for t in params.trace_ids]
        gates.gate("plan", _plan_summary(plans, total))
        runs = []
        for index, (trace_id, plan) in enumerate(zip(params.trace_ids, plans)):
            steps.ctx.progress(0.4 * index / total, f"trace {index + 1}/{total}: probing")
            runs.append((plan, steps.run("probe_run", {"plan_job_id": plan.id, **run_params(params)}, trace_id)))
        return None, runs, 0
    base = plan_params(params, placed, dialect, None)
    pilot = {"verify_count": 0, "pilot": True} if is_sequential(params) else {}  # coarse; the last round verifies
    plan = steps.run("probe_plan", {**base, **pilot}, None)
    gates.gate("plan", _plan_summary([plan], total))
    steps.ctx.progress(0.05, f"probing all {total} traces")
    probe = steps.run("probe_run", {"plan_job_id": plan.id, **run_params(params)}, None)
    plan, probe = more_rounds(steps, params, base, plan, probe, 0.05)
    runs = [(plan, probe)]
    for round_, asked in enumerate(gates.decisions.replans, start=1):  # stations an operator added
        prior: dict[str, Any] = {k: asked[k] for k in ("deviation_amplitude_mm", "deviation_wavelength_mm")
                                 if k in asked}
        following = steps.run("probe_plan", {**base, **prior, "fixed_run_job_id": probe.id,
                                             "touch_budget": asked.get("touch_budget") or params.touch_budget}, None)
        gates.gate("plan", _plan_summary([following], total), round_=round_)
        if ProbePlanResult.of(following).count:
            steps.ctx.progress(0.1, f"round {round_} asked by an operator: "
                               f"{ProbePlanResult.of(following).count} touches")
            plan, probe = following, steps.run("probe_run", {"plan_job_id": following.id, **run_params(params)},
                                               None)
            runs.append((plan, probe))
    return (plan, probe), runs, len(gates.decisions.replans)


SUMMARY_TRACES = 200  # a pause's summary lists at most this many traces (the children hold every one)


def _plan_summary(plans: list[Job], total: int) -> dict[str, Any]:
    """What the operator reviews before anything moves: touches and their predicted error."""
    results = [ProbePlanResult.of(p) for p in plans]
    touches = sum(r.count for r in results)
    sds = [t.predicted_sd_mm for r in results for t in (r.traces or ()) if t.predicted_sd_mm is not None]
    worst = 3 * max(sds) if sds else None
    line = f"{touches} touches on {total} trace(s)" + ("" if worst is None else
                                                       f"; predicted error (3 sigma) <= {worst * 1000:.1f} um")
    return {"headline": line, "touches": touches, "predicted_error_mm": worst, "plans": [p.id for p in plans]}


def _probed_summary(runs: list[tuple[Job, Job]], total: int) -> dict[str, Any]:
    """The touches made (the last run of each trace or of the joint plan: it holds them all)."""
    stats = [(run.result or {}).get("stats") or {} for _plan, run in runs]
    touches = sum(int(s.get("count") or 0) for s in stats)
    worst = max((float(s["max_abs_mm"]) for s in stats if s.get("max_abs_mm") is not None), default=None)
    line = f"{touches} touches made on {total} trace(s)" + ("" if worst is None else
                                                            f"; largest |real - model| {worst * 1000:.1f} um")
    return {"headline": line, "touches": touches, "max_abs_mm": worst, "runs": [run.id for _plan, run in runs]}


def _verified_summary(result: dict[str, Any], traces: list[dict[str, Any]]) -> dict[str, Any]:
    """Every trace rebuilt and compensated, and the field's verdict when there is one."""
    verdict = result.get("verdict")
    worst = max((t["deviation_max_mm"] for t in traces), default=0.0)
    line = verdict["verified"] if verdict else f"{len(traces)} trace(s) rebuilt and compensated"
    if verdict and verdict["needs_attention"]:
        line = f"NEEDS ATTENTION: {verdict['reasons'][0]}"
    keep = ("trace_id", "deviation_max_mm", "bound_mm", "worse_than_nominal", "held_ends_mm", "compensate",
            "print_artifact")
    return {"headline": line, "deviation_max_mm": worst, "verdict": verdict, "trace_count": len(traces),
            "traces": [{k: t[k] for k in keep if k in t} for t in traces[:SUMMARY_TRACES]],
            "held_ends": [t["trace_id"] for t in traces if t.get("held_ends_mm")]}


def _print_summary(traces: list[dict[str, Any]], params: ClosedLoopParams) -> dict[str, Any]:
    what = "print the nominal and the compensated program of" if params.evaluate else "print"
    return {"headline": f"{what} {len(traces)} trace(s) on machine {params.machine_id}: the machine will move",
            "trace_count": len(traces), "compensate": [t["compensate"] for t in traces[:SUMMARY_TRACES]]}


def _field_check(rebuilt: Job, trace_id: str, entry: dict[str, Any], plan: Job,
                 typed: TypedResults) -> dict[str, Any] | None:
    """A field reconstruct child's check (the same dict object for every trace of one child);
    fills the trace's ``bound_mm`` and ``worse_than_nominal``.  None for other methods."""
    result = rebuilt.result or {}
    check = result.get("field_check")
    if check is None:
        return None
    row = typed.reconstruct_rows(rebuilt)[trace_id]
    entry["bound_mm"] = row.bound_mm
    entry["worse_than_nominal"] = typed.trace_index(plan, trace_id) in check.get("worse_traces", [])
    return check


def retouched(plan: Job) -> list[dict[str, Any]]:
    """The touches of a field plan that were touches again of a suspected outlier: station
    (index in the plan's field), xy, trace and ``retouch_of`` (the station touched again);
    none for a scan."""
    if plan.kind != "probe_plan":
        return []
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
                "add stations and refit: POST /jobs/{id}/add-stations (one more round planned from the run, "
                "with suggested_probe, the fitted prior, as its start)",
                "or accept explicitly: POST /jobs/{id}/accept (the loop prints what it holds and says it was "
                "accepted)"]}


