"""Job ``probe_plan``: where to probe a trace (or several traces of one part), and the
probe program (G-code).

With ``placement`` or ``registration_job_id`` the trace (and the part, for safe travel
heights) is first mapped into machine coordinates, so the probes land on the part where
it really sits; without, the part frame is the machine frame (unchanged behaviour).

With ``trace_ids`` (part-level probing) one program touches every trace in the given
order; with the ``kriging`` planner the stations of all traces are designed together
(:func:`app.probing.joint.plan_joint`).  The result's ``traces`` give each trace's range
``[first, first + count)`` in ``points`` / ``records`` (and so in the probe run's points).

The ``field`` planner (the default with ``trace_ids``) designs stations over the region the
traces cover, as one field (:func:`app.probing.field.plan_field`): its result's ``field``
lists the stations in probing order with the trace each lies on (-1: off the traces), and
``traces`` gives per trace its station count and predicted sd (no ranges: stations are
shared).  Reconstruct each trace with ``method: "field"`` from the run."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Any

import numpy as np

from app.domain.errors import InvalidInput
from app.jobs.field_runs import field_touches, measured_array, touched_stations, touched_verification
from app.jobs.gcode_meta import gcode_meta
from app.jobs.inputs import (
    check_registration,
    placed_nominal,
    placed_nominals,
    placement_from,
    registration_reference,
)
from app.jobs.params import ProbePlanParams
from app.jobs.results.models import ProbePlanResult
from app.probing import PlanParams, ProbePlan, ProbeProgram, build_probe_program, plan_probes
from app.probing.field import plan_field
from app.probing.field_reuse import PlanReuse
from app.probing.field_stored import field_result, stored_field
from app.probing.field_top import mesh_top_sampler
from app.probing.field_verify import with_sequential_verification, with_verification
from app.probing.joint import plan_joint
from app.probing.merge import merge_plans
from app.probing.program import mesh_station_normals
from app.reconstruction.field import fit_field
from app.reconstruction.field_learning import MIN_TOUCHES, learn_prior
from app.reconstruction.field_sequential import decide_round, pilot_params, round_params
from app.reconstruction.field_surprise import surprise
from app.runtime.context import JobContext
from app.runtime.reads import JobReads
from app.runtime.registry import job_kind


def check_same_part(reads: JobReads, trace_ids: list[str], field: str) -> None:
    """Submission check: the traces exist, are distinct and all lie on the first one's part;
    otherwise a 422 naming ``{field}.<i>``."""
    seen: dict[str, int] = {}
    part_id = None
    for index, trace_id in enumerate(trace_ids):
        if trace_id in seen:
            raise InvalidInput(f"trace {trace_id!r} is listed twice (also at {field}.{seen[trace_id]})",
                               field=f"{field}.{index}", value=trace_id)
        seen[trace_id] = index
        trace = reads.find_trace(trace_id)
        if trace is None:
            raise InvalidInput(f"trace {trace_id!r} does not exist", field=f"{field}.{index}", value=trace_id)
        part_id = part_id or trace.part_id
        if trace.part_id != part_id:
            raise InvalidInput(f"trace {trace_id!r} is on part {trace.part_id!r}, not on part {part_id!r} like "
                               f"{field}.0: one plan probes one part", field=f"{field}.{index}", value=trace_id)


def _check(params: ProbePlanParams, reads: JobReads) -> None:
    check_registration(params, reads)
    if params.trace_ids is not None:
        check_same_part(reads, params.trace_ids, "params.trace_ids")


def _references(params: ProbePlanParams) -> list[tuple[str, str]]:
    traces = params.trace_ids if params.trace_ids is not None else [params.trace_id]
    return [*(("trace", t) for t in traces if t is not None), *registration_reference(params)]


def _plan_params(params: ProbePlanParams) -> PlanParams:
    """The planners' parameters (:meth:`ProbePlanParams.plan_params`: the job's, by name)."""
    return params.plan_params()


def _program(ctx: JobContext, params: ProbePlanParams, plan: ProbePlan, mesh: Any) -> tuple[ProbeProgram, dict]:
    """Build the probe program of ``plan`` over ``mesh``, store it; (program, its G-code meta).
    Stations without a planned normal take the placed mesh's face normal below them."""
    if plan.normals is None:
        plan = replace(plan, normals=mesh_station_normals(mesh, plan.points[:, :2]))
    program = build_probe_program(plan, mesh, params.program_params(float(mesh.bounds[1][2])), job_id=ctx.job_id)
    meta = gcode_meta(program.gcode)
    ctx.artifact("probe.gcode", program.gcode.encode(), "text/x-gcode", meta)
    return program, meta


@job_kind("probe_plan", ProbePlanParams, check=_check, references=_references)
def run(ctx: JobContext, params: ProbePlanParams) -> dict:
    """Plan probe points on a trace or on several traces of one part, and write the probe program.

    The traces are placed into machine coordinates first when asked."""
    if params.planner == "field":
        return _run_field(ctx, params, params.trace_ids or [str(params.trace_id)])
    if params.trace_ids is not None:
        return _run_joint(ctx, params, params.trace_ids)
    trace = ctx.trace(str(params.trace_id))
    placement = placement_from(ctx, params)
    mesh = ctx.placed_mesh(ctx.part(trace.part_id), placement)
    ctx.progress(0.1, "planning probe points")
    plan = plan_probes(placed_nominal(trace, placement), params.planner, _plan_params(params))
    ctx.progress(0.5, f"{plan.count} probe points; writing the program")
    program, meta = _program(ctx, params, plan, mesh)
    result = {
        "count": plan.count,
        "method": plan.method,
        "points": plan.points.tolist(),
        "s_mm": plan.s_mm.tolist(),
        "records": [r.to_dict() for r in program.records],
        "spacing_mm": plan.spacing_mm,
        "trace_length_mm": trace.length_mm,
        "program": meta,
    }
    if placement is not None:
        result["placement"] = placement.to_dict()
    if plan.point_count is not None:
        result["point_count"] = {"count": plan.point_count.count, "n_exact": plan.point_count.n_exact,
                                 "z_gamma": plan.point_count.z_gamma}
    return ProbePlanResult.written(result)


def _run_joint(ctx: JobContext, params: ProbePlanParams, trace_ids: list[str]) -> dict:
    """Part-level plan: stations per trace (jointly for kriging), one program in trace order."""
    traces = ctx.traces(trace_ids, nominals=False)  # one query, not one per trace
    placement = placement_from(ctx, params)
    mesh = ctx.placed_mesh(ctx.part(traces[0].part_id), placement)
    nominals = placed_nominals(ctx, traces, placement)
    ctx.progress(0.1, f"planning probe points on {len(traces)} traces")
    if params.planner == "kriging":
        plans = plan_joint(nominals, _plan_params(params))
    else:
        plans = tuple(plan_probes(nominal, params.planner, _plan_params(params)) for nominal in nominals)
    combined, firsts = merge_plans(plans, params.planner)
    ctx.progress(0.5, f"{combined.count} probe points on {len(traces)} traces; writing the program")
    program, meta = _program(ctx, params, combined, mesh)
    result = {
        "count": combined.count,
        "method": params.planner,
        "points": combined.points.tolist(),
        "s_mm": combined.s_mm.tolist(),
        "records": [r.to_dict() for r in program.records],
        "program": meta,
        "traces": [{"trace_id": trace.id, "first": int(first), "count": plan.count, "s_mm": plan.s_mm.tolist(),
                    "trace_length_mm": trace.length_mm, "predicted_sd_mm": plan.predicted_sd_mm}
                   for trace, plan, first in zip(traces, plans, firsts)],
    }
    if placement is not None:
        result["placement"] = placement.to_dict()
    return ProbePlanResult.written(result)


def _field_entry(plan: Any, plan_params: PlanParams, params: ProbePlanParams,
                 sequential: dict[str, Any] | None) -> dict[str, Any]:
    """The result's ``field``: the plan's stations (after a sequential round's touched ones)."""
    entry = {**field_result(plan, plan_params.prior()), "coverage": params.coverage,
             "target_error_mm": params.target_error_mm, "verify_count": int(plan.verify_mask.sum())}
    if sequential is not None:
        own = entry["stations"]
        marks = sequential.get("retouch_of", [])
        first = len(own) - int(plan.verify_mask.sum()) - len(marks)
        for k, original in enumerate(marks):
            own[first + k]["retouch_of"] = original
        entry["stations"] = sequential.pop("fixed") + own
        entry["verify_count"] = sum(bool(st.get("verify")) for st in entry["stations"])
        entry["center"] = sequential.pop("center")
        entry["sequential"] = sequential
    return entry


RETOUCHES = 2  # a suspected outlier is touched again, and once more if the two disagree


def _retouches(prior: Any, sites: Any, dz: np.ndarray, field: Any, keep: np.ndarray,
               fixed: list[dict[str, Any]]) -> list[int]:
    """Indices into ``fixed`` of the touches the fitted field would exclude as outliers
    (leave-one-out, :func:`app.reconstruction.field.fit_field`) that were not yet touched
    again RETOUCHES times (a re-touch names its original in ``retouch_of``)."""
    fit = fit_field(prior, sites, field.z[keep], np.column_stack([sites.xy, field.z[keep] + dz]), field.center)
    again = Counter(int(st["retouch_of"]) for st in fixed if st.get("retouch_of") is not None)
    out = []
    for i in fit.outliers:
        original = int(fixed[i].get("retouch_of", i))
        if again[original] < RETOUCHES and original not in out:
            out.append(original)
    return out


def _retouched(plan: Any, field: Any, keep: np.ndarray, retouch: list[int]) -> Any:
    """``plan`` (a field plan of the same traces) touching only the fit stations ``retouch``
    (indices among the kept ones of the stored ``field``) again, nothing else."""
    idx = np.flatnonzero(keep)[retouch] if retouch else np.zeros(0, dtype=int)
    return replace(plan, xy=field.stations.xy[idx], z=field.z[idx], grad=field.stations.grad[idx],
                   trace=field.trace[idx], s_mm=field.s_mm[idx], order=np.arange(len(idx)), verify=None)


def _next_round(ctx: JobContext, params: ProbePlanParams, nominals: list[Any], plan_params: PlanParams,
                top: Any) -> tuple[Any, PlanParams, dict[str, Any]]:
    """A sequential round: learn the prior from every station touched so far (the fixed
    run's field) and decide the round as the core's loop does
    (:func:`app.reconstruction.field_sequential.decide_round`: the stations the fitted field
    still needs at the round's pointwise target, kept for the next round as
    ``plan_target_mm``; the run's bound when it needs none); the rounds ended (the bound
    holds, no station helps, past the touch budget) or on the loop's ``last_round``: only the
    verification points.  A suspected outlier is touched again before the bound is judged.
    Returns (the plan of what this round touches, the learned plan parameters, the round's
    record incl. the fixed stations)."""
    run = ctx.job(str(params.fixed_run_job_id), kind="probe_run", field="params.fixed_run_job_id")
    plan_job = ctx.job(run.params["plan_job_id"], field="params.fixed_run_job_id")
    if not ProbePlanResult.of(plan_job).field or plan_job.params.get("trace_ids") != params.trace_ids:
        raise InvalidInput(f"probe run {run.id!r} is not a run of a field plan of the same traces",
                           field="params.fixed_run_job_id", value=run.id)
    assert plan_job.result is not None  # it holds the field plan read above
    stored, rows = field_touches(ctx, run)
    field = stored_field(stored)
    fixed = touched_stations(stored, run.id)
    keep = ~field.verify
    dz = measured_array(rows)[keep, 2] - field.z[keep]
    sites = field.stations.take(np.flatnonzero(keep))
    learned = learn_prior(plan_params.prior(), sites, dz, field.center)
    before = plan_job.result.get("field", {}).get("sequential", {})
    plan_target = float(before.get("plan_target_mm", plan_params.target_error_mm))
    suspect = learned.prior
    if params.retouch_only:  # judged at the probe's repeatability: one bad touch inflates the learned noise
        suspect = replace(suspect, sigma_mm=min(suspect.sigma_mm, plan_params.probe_sigma_mm))
    retouch = _retouches(suspect, sites, dz, field, keep, fixed)

    reuse = PlanReuse()   # what the round's plans share

    def plan(at: PlanParams) -> Any:
        return plan_field(nominals, at, params.stations, top, fixed=sites, reuse=reuse)
    if params.retouch_only:  # the prior stays the user's: a single-shot plan's second run
        at = replace(round_params(plan_params, learned.prior, field.prior.wavelength_mm), target_error_mm=plan_target)
        return _retouched(plan(at), field, keep, retouch), plan_params, {
            "round": int(plan_job.result.get("field", {}).get("sequential", {}).get("round", 0)) + 1,
            "final": True, "stopped": "retouched", "added": 0, "touched_before": len(fixed),
            "learned": learned.as_dict(), "retouch_of": [int(i) for i in retouch],
            "fixed": fixed + touched_verification(stored, run.id), "center": stored["center"]}
    budget = params.touch_budget
    room = None if budget is None else budget - len(fixed) - len(retouch) - params.verify_count
    decision = decide_round(plan_params, learned, sites, dz, field.trace[keep], field.s_mm[keep], field.center,
                            nominals, plan, plan_target, field.prior.wavelength_mm, room, judge=not retouch,
                            first=not before)
    more, learned_params, bound = decision.more, decision.params, decision.bound_mm
    plan_target = learned_params.target_error_mm
    final = decision.stopped is not None or params.last_round
    stopped = decision.stopped or ("rounds" if params.last_round else None)
    if not final and retouch:  # a suspected outlier is touched again before the fit may exclude it
        idx = np.flatnonzero(keep)[retouch]
        more = replace(more, xy=np.concatenate([more.xy, field.stations.xy[idx]]),
                       z=np.concatenate([more.z, field.z[idx]]),
                       grad=np.concatenate([more.grad, field.stations.grad[idx]]),
                       trace=np.concatenate([more.trace, field.trace[idx]]),
                       s_mm=np.concatenate([more.s_mm, field.s_mm[idx]]),
                       order=np.arange(more.count + len(idx)))
    if final:  # no stations: the verification points for every station touched so far
        more = replace(more, xy=more.xy[:0], z=more.z[:0], grad=more.grad[:0], trace=more.trace[:0],
                       s_mm=more.s_mm[:0], order=more.order[:0])
        fitted = np.setdiff1d(np.arange(len(dz)), learned.screened)  # the learning's LOO: its unscreened touches
        surprised = surprise(learned.prior, sites.take(fitted), dz[fitted], field.center, field.trace[keep][fitted],
                             field.s_mm[keep][fitted])  # the gaps beside the worst predicted
        more = with_sequential_verification(more, sites, nominals, learned_params.prior(), params.verify_count,
                                            surprised)
    return more, learned_params, {
        "round": int(plan_job.result.get("field", {}).get("sequential", {}).get("round", 0)) + 1,
        "final": final, "stopped": stopped, "plan_target_mm": plan_target,
        "bound_mm": bound, "added": 0 if final else more.count - len(retouch), "touched_before": len(fixed),
        "learned": learned.as_dict(), "retouch_of": [] if final else [int(i) for i in retouch],
        "fixed": fixed, "center": stored["center"]}


def _run_field(ctx: JobContext, params: ProbePlanParams, trace_ids: list[str]) -> dict:
    """Board plan: stations over the region the traces cover, one program in probing order."""
    traces = ctx.traces(trace_ids, nominals=False)  # one query, not one per trace
    placement = placement_from(ctx, params)
    mesh = ctx.placed_mesh(ctx.part(traces[0].part_id), placement)
    nominals = placed_nominals(ctx, traces, placement)
    ctx.progress(0.1, f"planning field stations over {len(traces)} traces")
    plan_params = _plan_params(params)
    top = mesh_top_sampler(mesh) if params.stations == "anywhere_on_top" else None
    sequential = None
    if params.fixed_run_job_id is not None:
        plan, plan_params, sequential = _next_round(ctx, params, nominals, plan_params, top)
    else:
        designed = None
        if params.pilot:  # coarse, unless too coarse to learn the prior from: then the user's design
            coarse = pilot_params(plan_params)
            designed = plan_field(nominals, coarse, params.stations, top)
            if designed.count >= MIN_TOUCHES:
                plan_params = coarse
            else:
                designed = None
        if designed is None:
            designed = plan_field(nominals, plan_params, params.stations, top)
        plan = with_verification(designed, nominals, plan_params.prior(), params.verify_count)
    ctx.progress(0.5, f"{plan.count - int(plan.verify_mask.sum())} stations and {int(plan.verify_mask.sum())} "
                 f"verification points for {len(traces)} traces (field: {plan.dof:.0f} degrees of "
                 f"freedom at the target, {plan.nyquist_dof:.0f} by the Nyquist rule); writing the program")
    if plan.count:
        program, meta = _program(ctx, params, plan.probe_plan(), mesh)
        records = [r.to_dict() for r in program.records]
    else:  # a round with nothing to touch (no suspected outlier to touch again): no program
        records, meta = [], {}
    field = _field_entry(plan, plan_params, params, sequential)
    on = [st["trace"] for st in field["stations"] if st["trace"] >= 0 and not st.get("verify")]
    counts = np.bincount(np.asarray(on, dtype=int), minlength=len(traces))
    result = {
        "count": plan.count,
        "method": "field",
        "points": plan.points.tolist(),
        "s_mm": [None if np.isnan(s) else float(s) for s in plan.s_mm],
        "records": records,
        "program": meta,
        "field": field,
        "traces": [{"trace_id": trace.id, "index": i, "stations": int(counts[i]), "trace_length_mm": trace.length_mm,
                    "predicted_sd_mm": float(plan.trace_sd_mm[i])} for i, trace in enumerate(traces)],
    }
    if placement is not None:
        result["placement"] = placement.to_dict()
    return ProbePlanResult.written(result)
