"""The touches of a field plan's probe run, with the stations an earlier run touched.

A sequential field plan (``probe_plan`` with ``fixed_run_job_id``) lists every station the
field is fitted from: the ones earlier runs touched (``from_run``: that probe run's id,
``run_index``: the point's index among that run's points) and its own, which its probe run
touches (in order, after the earlier ones).  :func:`field_touches` puts the measured points
of all of them in the plan's station order, for the reconstruction and for the next round's
learning; :func:`run_field` the run's checked field (learned, fitted and verified once per
run, probe noise and learning switch, and cached), which every trace's reconstruction and the
circuit program's fills evaluate.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from app.domain.errors import InvalidInput
from app.geometry.placement import Placement
from app.jobs.probe_correction import refined, run_probe_calibration
from app.jobs.results.models import ProbePlanResult, ProbeRunResult
from app.parts.lru import BackedLru
from app.platform.models import Job
from app.probing.field_stored import stored_field
from app.probing.field_top import mesh_top_sampler
from app.reconstruction.field import field_gradient, fit_bytes
from app.reconstruction.field_trust import FieldCheck, checked_field
from app.runtime.context import JobContext

FIELD_FITS = BackedLru(64 * 2 ** 20)
"""Fitted fields of field-plan probe runs by (run id, sigma): fitted once per process, and
once per service when a compute process gives it a disk tier (``FIELD_FITS.backing``)."""


def _rows(job: Job) -> list[dict[str, Any]]:
    return sorted(ProbeRunResult.of(job).rows(), key=lambda p: p["index"])


def field_touches(ctx: JobContext, run: Job) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(the run's plan's stored field, its probe points aligned with the field's stations).
    Raises if the run's plan is not a field plan (checked by the callers first)."""
    plan = ctx.job(run.params["plan_job_id"], field="params.probe_run_job_id")
    stored = ProbePlanResult.of(plan).field
    assert stored is not None
    own = _rows(run)
    earlier: dict[str, list[dict[str, Any]]] = {}
    out, j = [], 0
    for station in stored["stations"]:
        source = station.get("from_run")
        if source:
            if source not in earlier:
                earlier[source] = _rows(ctx.job(source, kind="probe_run", field="params.probe_run_job_id"))
            out.append(earlier[source][int(station["run_index"])])
        else:
            out.append(own[j])
            j += 1
    return stored, out


def _touched(stored: dict[str, Any], run_id: str, verify: bool) -> list[dict[str, Any]]:
    """The stations (``verify`` False) or verification points (True) of a run's field, each
    naming the run that touched it (``from_run``, ``run_index``)."""
    out, own = [], 0
    for station in stored["stations"]:
        if station.get("from_run"):
            source, index = station["from_run"], station["run_index"]
        else:
            source, index = run_id, own
            own += 1
        if bool(station.get("verify")) == verify:
            out.append({**station, "from_run": source, "run_index": int(index)})
    return out


def touched_stations(stored: dict[str, Any], run_id: str) -> list[dict[str, Any]]:
    """The fit stations (not verification points) of a run's field, each naming the run
    that touched it (``from_run``, ``run_index``): the fixed stations of the next round."""
    return _touched(stored, run_id, verify=False)


def touched_verification(stored: dict[str, Any], run_id: str) -> list[dict[str, Any]]:
    """The verification points of a run's field, named like :func:`touched_stations`: kept
    by a round that only touches outliers again."""
    return _touched(stored, run_id, verify=True)


def measured_array(rows: list[dict[str, Any]]) -> np.ndarray:
    """(n, 3) measured points of aligned rows."""
    return np.array([p["measured"] for p in rows], dtype=float).reshape(-1, 3)


def run_field(ctx: JobContext, probe_run_job_id: str, sigma_mm: float | None, learn_prior: bool,
              traces: list[str], placement: Placement | None, *, method: str = "field",
              trace_field: str = "params.trace_id") -> tuple[FieldCheck, Any, list[str]]:
    """(checked field, normal-iteration report or None, the plan's trace ids) of the field of
    probe run ``probe_run_job_id``, with probe noise ``sigma_mm`` (None: the plan's prior's)
    and ``learn_prior``; fitted once per (run, sigma, learning) and cached.  ``traces`` must be
    traces of the run's plan (422 on ``trace_field`` otherwise); a run of another plan is a 422
    on ``params.method`` (value ``method``).  ``placement``: the frame the run was probed in
    (the calibrated radius correction samples the placed part's slopes)."""
    probe_run = ctx.job(probe_run_job_id, kind="probe_run", field="params.probe_run_job_id")
    plan = ctx.job(probe_run.params["plan_job_id"], field="params.probe_run_job_id")
    stored = ProbePlanResult.of(plan).field
    if not stored:
        raise InvalidInput(f"probe run {probe_run.id!r} is not a run of a field plan", field="params.method",
                           value=method)
    trace_ids = plan.params.get("trace_ids") or [plan.params.get("trace_id")]
    missing = set(traces) - set(trace_ids)
    if missing:
        trace_id = next(t for t in traces if t in missing)
        raise InvalidInput(f"trace {trace_id!r} is not one of the traces of field plan {plan.id!r}",
                           field=trace_field, value=trace_id)
    key = (probe_run.id, sigma_mm, learn_prior)
    cached = FIELD_FITS.get(key)
    if cached is None:
        field = stored_field(stored)
        prior = field.prior if sigma_mm is None else replace(field.prior, sigma_mm=sigma_mm)
        rows = field_touches(ctx, probe_run)[1]  # with the stations earlier runs of a sequential plan touched
        plan_params = plan.params or {}
        coverage = float(stored.get("coverage", plan_params.get("coverage", 3.0)))
        target = float(stored.get("target_error_mm", plan_params.get("target_error_mm", 0.005)))

        def fit_of(points: Any) -> FieldCheck:
            return checked_field(prior, field.stations, field.z, np.asarray(points, dtype=float), field.center,
                                 field.trace, field.s_mm, field.verify, coverage, target, learn=learn_prior,
                                 field="probe run points")

        check = fit_of([p["measured"] for p in rows])
        calibration = run_probe_calibration(probe_run)
        refinement = None
        if calibration is not None:
            stations = field.stations
            trace = ctx.trace(traces[0])
            top = mesh_top_sampler(ctx.placed_mesh(ctx.part(trace.part_id), placement))
            check, refinement = refined(check, rows, calibration, lambda c, _xy: field_gradient(
                c.fit, stations, slope_at=lambda xy: top(xy).grad), fit_of)
        cached = (check, refinement)
        FIELD_FITS.put(key, cached, fit_bytes(check.fit))
    check, refinement = cached
    return check, refinement, trace_ids
