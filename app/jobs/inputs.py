"""Loading what job parameters point to, shared by the job kinds (a kind never imports another).

* THE check "job ``job_id`` is a succeeded job of kind K" is
  :meth:`app.runtime.reads.JobReads.succeeded_job` at submission (and, through
  :meth:`app.runtime.context.JobContext.job`, when a job runs);
* placements: :func:`check_registration` (submission), :func:`placement_from` (run),
  :func:`registration_reference`, :func:`placed_params_of` (what a stored job was placed by);
* a trace's stored nominal polyline: :func:`nominal_of`, :func:`placed_nominal`, a board's
  :func:`placed_nominals`.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING

from app.geometry.placement import Placement
from app.geometry.traces import TracePolyline
from app.jobs.held_nominals import HELD, held_polyline
from app.jobs.params import PlacedParams, PlacementParams
from app.jobs.results.models import RegisterResult
from app.parts.lru import ByteLru
from app.platform.models import Job, Trace
from app.registration.registration import place_path

if TYPE_CHECKING:
    from app.runtime.context import JobContext
    from app.runtime.reads import JobReads


# placements -------------------------------------------------------------------------------
def registration_reference(params: PlacedParams) -> list[tuple[str, str]]:
    return [("job", params.registration_job_id)] if params.registration_job_id else []


def check_registration(params: PlacedParams, reads: JobReads) -> Placement | None:
    """Submission check: the referenced job is a succeeded register job; its placement."""
    if params.registration_job_id is None:
        return None if params.placement is None else params.placement.to_placement()
    job = reads.succeeded_job(params.registration_job_id, "register", "params.registration_job_id")
    return PlacementParams.model_validate(RegisterResult.of(job).placement).to_placement()


def placed_params_of(job: Job) -> PlacedParams:
    """The placement part (``placement`` / ``registration_job_id``) of a job's stored parameters."""
    return PlacedParams.model_validate({k: job.params[k] for k in ("placement", "registration_job_id")
                                        if job.params.get(k) is not None})


def placement_from(ctx: JobContext, params: PlacedParams) -> Placement | None:
    """The placement ``params`` asks for (explicit, or a register job's), else None."""
    if params.registration_job_id is not None:
        job = ctx.job(params.registration_job_id, kind="register", field="params.registration_job_id")
        return PlacementParams.model_validate(RegisterResult.of(job).placement).to_placement()
    return None if params.placement is None else params.placement.to_placement()


# nominal traces ---------------------------------------------------------------------------
def nominal_of(trace: Trace) -> TracePolyline:
    """The stored draped nominal polyline of a trace (``Trace.nominal``, the stored JSON)."""
    return TracePolyline.from_dict(trace.nominal, field="trace.nominal")


def placed_nominal(trace: Trace, placement: Placement | None) -> TracePolyline:
    """The trace's nominal in machine coordinates (unchanged without a placement): the one
    this process holds for the stored trace and placement (:mod:`app.jobs.held_nominals`,
    read-only arrays), else parsed and held."""
    def make() -> TracePolyline:
        nominal = nominal_of(trace)
        return nominal if placement is None else place_path(nominal, placement)
    if trace.id is None or trace.created_at is None:  # not a stored trace
        return make()
    return held_polyline((trace.id, trace.created_at, placement), make)


def placed_nominals(ctx: JobContext, traces: list[Trace], placement: Placement | None,
                    held: ByteLru = HELD) -> list[TracePolyline]:
    """:func:`placed_nominal` of each of ``traces`` (stored traces, read with or without their
    nominals: ``JobContext.traces(..., nominals=False)``), the nominals this process does not
    hold yet (in ``held``) read in one query: a board's later jobs read and decode none."""
    keys = [(trace.id, trace.created_at, placement) for trace in traces]
    missing = [trace.id for trace, key in zip(traces, keys) if held.get(key) is None]
    stored = ctx.trace_nominals(missing) if missing else {}

    def make(trace_id: str) -> TracePolyline:
        if trace_id not in stored:  # let go since the look above (more traces than the process holds)
            stored.update(ctx.trace_nominals([trace_id]))
        nominal = TracePolyline.from_dict(stored.pop(trace_id), field="trace.nominal")
        return nominal if placement is None else place_path(nominal, placement)
    return [held_polyline(key, partial(make, trace.id), held) for trace, key in zip(traces, keys)]
