"""The step machinery of a ``closed_loop`` job: its children, submitted and awaited.

:class:`Steps` runs one child job per step and reuses a succeeded child with exactly the
same kind and (validated) parameters, of this attempt or an earlier one: a loop that ran
again (its worker died, an operator resumed or continued it) never probes a finished trace
again.  The helpers below build each step's parameters from the loop's
(:class:`app.jobs.kinds.closed_loop.ClosedLoopParams`, passed in, never imported).

Trace ends (:func:`end_hold`): a trace whose end lies on a pad (a pad centre, say) may end
before the first / after the last probe of its own plan.  Within ``end_hold_max_mm`` the
compensation holds the deviation measured at the nearest probe over that gap and the
loop's row says so (``held_ends_mm``); beyond it the loop stops naming the trace and its
gap (a trace is never left out silently).
"""

from __future__ import annotations

import json
import math
from typing import Any

from pydantic import ValidationError

from app.domain.errors import Cancelled, ConformaError
from app.jobs.inputs import nominal_of
from app.jobs.results.models import (
    CompensateBoardResult,
    CompensateResult,
    ProbePlanResult,
    ReconstructResult,
    program_artifacts,
    reconstruct_rows,
)
from app.jobs.simulation import evaluate_print, xy_error
from app.platform.models import Job, Machine
from app.reference.evaluation import predicted_width, table_row
from app.runtime.context import JobContext
from app.runtime.registry import kinds

Done = tuple[str, Job, Job, Job, Job, float, tuple[str, str]]
"""One trace's children: (trace_id, plan, probe run, reconstruct, compensate, deviation max mm,
(print artifact, nominal artifact))."""
HOLD_ROUND_MM = 0.001  # a held gap is rounded up to this (mm)


class Steps:
    """Runs child jobs, reusing a succeeded child of this parent (this attempt or an earlier
    one) that had exactly the same kind and (validated) parameters."""

    def __init__(self, ctx: JobContext) -> None:
        self.ctx = ctx
        with ctx.reads() as reads:
            done = reads.succeeded_children(ctx.job_id)
        self.reusable = {(j.kind, json.dumps(j.params, sort_keys=True)): j for j in done}

    def run(self, kind: str, params: dict[str, Any], trace_id: str | None) -> Job:
        normalized = kinds()[kind].params.model_validate(params).model_dump(mode="json")
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
        self.reusable[key] = job
        return job


def scan_params(params: dict[str, Any]) -> dict[str, Any]:
    """A closed loop's scan_run parameters, validated by the kind's model (ValueError naming the field)."""
    try:
        out: dict[str, Any] = kinds()["scan_run"].params.model_validate(params).model_dump(mode="json")
    except ValidationError as exc:
        first = exc.errors()[0]
        raise ValueError(f"scan.{'.'.join(str(p) for p in first['loc'])}: {first['msg']}") from None
    return out


def measured_by(plan: Job, probe: Job) -> dict[str, str]:
    """A loop row's measuring children: the scan_run, or the probe plan and probe run."""
    if probe.kind == "scan_run":
        return {"scan_run": probe.id}
    return {"probe_plan": plan.id, "probe_run": probe.id}


def scanned_summary(scan: Job, total: int) -> dict[str, Any]:
    """The ``probed`` pause after a scan: passes, samples, the verification touches and the bound."""
    result = scan.result or {}
    check = result.get("verification") or {}
    line = (f"{result.get('passes', 0)} scan passes, {result.get('valid', 0)}/{result.get('samples', 0)} valid "
            f"samples over {total} trace(s); bound {float(result.get('bound_mm') or 0.0) * 1000:.1f} um")
    return {"headline": line, "scan_run": scan.id, "passes": result.get("passes"), "samples": result.get("samples"),
            "valid": result.get("valid"), "bound_mm": result.get("bound_mm"),
            "verification_max_abs_mm": check.get("max_abs_residual_mm")}


def probe_rings(ctx: JobContext, trace_ids: list[str]) -> set[str]:
    """The pad / area probe rings among ``trace_ids`` (traces with ``source.role`` ``pad_probe``,
    made by a circuit import): probed and rebuilt with the traces, never printed."""
    with ctx.reads() as reads:
        sources = reads.trace_sources(trace_ids)
    return {trace_id for trace_id, source in sources.items() if source.get("role") == "pad_probe"}


def plan_params(params: Any, placed: dict[str, Any], dialect: str, trace_id: str | None) -> dict[str, Any]:
    """The probe_plan parameters of one trace, or (``trace_id`` None) of every trace together."""
    target: dict[str, Any] = {"trace_ids": params.trace_ids} if trace_id is None else {"trace_id": trace_id}
    default = {} if trace_id is None else {"method": "deviation"}  # joint: the planner's default (field)
    return {**default, **params.probe, **placed, **target, "dialect": dialect}


def run_params(params: Any) -> dict[str, Any]:
    return {"machine_id": params.machine_id, **corrections_for("probe_run", params)}


def is_sequential(params: Any) -> bool:
    return bool(params.sequential and params.probe.get("method", "field") == "field")


def more_rounds(steps: Steps, params: Any, base: dict[str, Any], plan: Job, probe: Job,
                progress: float) -> tuple[Job, Job]:
    """After a joint plan's first run: the sequential rounds (stations the fitted field still
    needs) or, single shot, one more touch of each suspected outlier."""
    run = run_params(params)
    if is_sequential(params):
        for round_ in range(params.max_rounds):  # the last one adds no stations: it verifies
            following = steps.run("probe_plan", {**base, "fixed_run_job_id": probe.id,
                                                 "touch_budget": params.touch_budget,
                                                 "last_round": round_ == params.max_rounds - 1}, None)
            field = ProbePlanResult.of(following).field or {}
            steps.ctx.progress(progress, f"sequential round {round_ + 1}: {field['sequential']['added']} stations "
                               f"added, {ProbePlanResult.of(following).count} touches")
            if ProbePlanResult.of(following).count == 0:
                break
            plan, probe = following, steps.run("probe_run", {"plan_job_id": following.id, **run}, None)
            if field["sequential"]["final"]:
                break
    elif ProbePlanResult.of(plan).field:
        # single shot: a touch the fitted field would exclude is touched once more before it may be
        again = steps.run("probe_plan", {**base, "fixed_run_job_id": probe.id, "retouch_only": True}, None)
        if ProbePlanResult.of(again).count:
            steps.ctx.progress(progress, f"{ProbePlanResult.of(again).count} suspected outliers touched again")
            plan, probe = again, steps.run("probe_run", {"plan_job_id": again.id, **run}, None)
    return plan, probe


def end_hold(params: Any, plan: Job, rebuilt: Job, trace_id: str) -> tuple[float, list[float] | None]:
    """The compensate ``hold_mm`` of one trace rebuilt from its own probes (not a field) and
    the gaps (before, after) mm it holds when they exceed the loop's ``hold_mm``; a gap beyond
    ``end_hold_max_mm`` stops the loop (ConformaError naming the trace and the gap)."""
    result = ReconstructResult.of(rebuilt)
    length = _trace_length(plan, trace_id)
    s = [row[0] for row in result.deviation.samples]
    if result.method == "field" or length is None or not s:
        return params.hold_mm, None
    before, after = max(min(s), 0.0), max(length - max(s), 0.0)
    need = max(before, after)
    if need <= params.hold_mm:
        return params.hold_mm, None
    if need > params.end_hold_max_mm:
        end = "start" if before >= after else "end"
        raise ConformaError(
            f"trace {trace_id}: its {end} lies {need:.3f} mm beyond its nearest probe (a pad?), more than "
            f"end_hold_max_mm {params.end_hold_max_mm:.3f} mm allows holding: probe that end (add a station there) "
            "or raise end_hold_max_mm", field="trace_ids", value=trace_id)
    hold = math.ceil(need / HOLD_ROUND_MM) * HOLD_ROUND_MM + HOLD_ROUND_MM
    return min(hold, params.end_hold_max_mm + HOLD_ROUND_MM), [round(before, 4), round(after, 4)]


def _trace_length(plan: Job, trace_id: str) -> float | None:
    result = ProbePlanResult.of(plan)
    if result.traces:
        return next((t.trace_length_mm for t in result.traces if t.trace_id == trace_id), None)
    return result.trace_length_mm


def trace_children(steps: Steps, params: Any, placed: dict[str, Any], plan: Job, probe: Job,
                   trace_id: str) -> tuple[Done, list[float] | None]:
    """A reconstruct and a compensate child of one trace, from ``probe`` (its own run, or the
    joint run of every trace), and the ends it holds (see :func:`end_hold`)."""
    prior = {k: params.probe[k] for k in ("deviation_amplitude_mm", "deviation_wavelength_mm") if k in params.probe}
    method = "field" if ProbePlanResult.of(plan).field else params.reconstruct_method
    rebuilt = steps.run("reconstruct", {**placement_of(params.probe), **placed, **prior,
                                        "trace_id": trace_id, "probe_run_job_id": probe.id,
                                        "method": method, "sigma_mm": params.sigma_mm,
                                        **corrections_for("reconstruct", params)}, trace_id)
    hold, held = end_hold(params, plan, rebuilt, trace_id)
    compensated = steps.run("compensate", {"trace_id": trace_id, "reconstruct_job_id": rebuilt.id,
                                           "machine_id": params.machine_id, "chord_error_mm": params.chord_error_mm,
                                           "hold_mm": hold, **tool_of(params)}, trace_id)
    return (trace_id, plan, probe, rebuilt, compensated, ReconstructResult.of(rebuilt).deviation.max_mm,
            program_artifacts(CompensateResult.of(compensated))), held


def board_batch(steps: Steps, params: Any, placed: dict[str, Any], shared: tuple[Job, Job],
                trace_ids: list[str]) -> list[Done]:
    """ONE reconstruct and ONE compensate child for a batch of a field plan's traces (or of a
    scan's: ``shared`` is then (the scan_run, the scan_run))."""
    plan, probe = shared
    source = {"scan_run_job_id": probe.id} if probe.kind == "scan_run" else {
        **placement_of(params.probe), **placed, "probe_run_job_id": probe.id, "sigma_mm": params.sigma_mm,
        **corrections_for("reconstruct", params)}
    rebuilt = steps.run("reconstruct", {**source, "trace_ids": trace_ids, "method": "field"}, None)
    compensated = steps.run("compensate", {"trace_ids": trace_ids, "reconstruct_job_id": rebuilt.id,
                                           "machine_id": params.machine_id, "chord_error_mm": params.chord_error_mm,
                                           "hold_mm": params.hold_mm, **tool_of(params)}, None)
    deviations = {t: row.deviation.max_mm for t, row in reconstruct_rows(rebuilt).items()}
    return [(r.trace_id, plan, probe, rebuilt, compensated, deviations[r.trace_id], program_artifacts(r))
            for r in CompensateBoardResult.of(compensated).traces]


class TypedResults:
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
        field plan's stations on that trace; none for a scan: it touches verification points only)."""
        if plan.kind == "scan_run":
            return 0
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


def print_trace(ctx: JobContext, steps: Steps, params: Any, machine: Machine, index: int,
                entry: dict[str, Any], rows: list[dict[str, Any]], hold_print: bool = False) -> None:
    """Print (or, with ``evaluate``, print both programs of and measure) one compensated trace;
    ``hold_print``: the field check asks for attention, so nothing is printed automatically
    (``evaluate``, a simulation on a mock machine, still measures both programs)."""
    trace_id = entry["trace_id"]
    artifacts = {"nominal.gcode": entry.get("nominal_artifact", "nominal.gcode"),
                 "print.gcode": entry.get("print_artifact", "print.gcode")}
    if params.evaluate:
        trace = ctx.trace(trace_id)
        world = ctx.machine_world(machine)  # built when the probe run connected
        assert world is not None  # evaluate runs on a mock machine (the kind checks it)
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


def corrections_for(kind: str, params: Any) -> dict[str, Any]:
    """The measuring corrections (radius, pretravel, drift) a child kind takes, as its
    ``corrections`` parameter lists them (nothing for a kind without one)."""
    fields = kinds()[kind].params.model_fields
    if "corrections" not in fields:
        return {}
    wanted = params.corrections.model_dump()
    annotation = fields["corrections"].annotation
    names = getattr(annotation, "model_fields", None)
    return {"corrections": {k: v for k, v in wanted.items() if names is None or k in names}}


def tool_of(params: Any) -> dict[str, Any]:
    """compensate's tool and offsets correction (defaults left out: the child's own)."""
    out: dict[str, Any] = {} if params.tool is None else {"tool": params.tool}
    if not params.corrections.offsets:
        out["corrections"] = {"offsets": False}
    return out


def placement_of(probe: dict[str, Any]) -> dict[str, Any]:
    """An explicit placement among the probe parameters also applies to the reconstruction."""
    return {k: probe[k] for k in ("placement", "registration_job_id") if k in probe}


def _report(report: Any, xy: Any) -> dict[str, float]:
    width = predicted_width(report)
    return {"standoff_error_max_mm": report.max_abs_error_mm, "standoff_error_rms_mm": report.rms_error_mm,
            "width_mean_mm": width.mean_mm, "width_std_mm": width.std_mm, "length_mm": report.length_mm,
            "xy_error_max_mm": xy.max_mm, "xy_error_rms_mm": xy.rms_mm}
