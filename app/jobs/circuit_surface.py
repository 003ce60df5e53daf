"""The measured surface a ``circuit_program`` prints on, from its closed loop.

A loop with a field plan (joint probing, the field planner) fitted ONE deviation field to its
run (:func:`app.jobs.field_runs.run_field`, the fit every trace's reconstruction evaluated,
learned and verified): the program's surface is the nominal top plus that field's posterior
mean, each point with its posterior sd and the bound coverage x sd.  Any other loop gives
the deviation interpolated between its probe stations (no sd).

A loop that worked in machine coordinates (a placement, or its registration) probed,
fitted and compensated there: the surface is then the PLACED part's top plus that
deviation, in the same machine frame as the compensated trace tips, and everything else the
program prints (pads, areas) is carried into that frame by :func:`loop_placement`'s
placement before it is filled.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from app.circuits.strokes import deviation_field
from app.circuits.surface import MeasuredSurface
from app.geometry.placement import Placement
from app.jobs.field_runs import run_field
from app.jobs.inputs import placement_from
from app.jobs.params import PlacedParams
from app.jobs.results.loop import LoopTrace
from app.jobs.results.models import ProbePlanResult
from app.probing.deviation_prior import Sites
from app.probing.field_top import mesh_top_sampler
from app.reconstruction.field_trust import FieldCheck
from app.runtime.context import JobContext

#: posterior sd evaluated this many points at a time (the cross-covariance is points x stations)
SD_CHUNK = 2000
#: the posterior sd judged every wavelength / 16 along each printed stroke (as the planner
#: and the traces' bounds judge it)
SD_PER_WAVELENGTH = 16


def loop_placement(ctx: JobContext, entries: dict[str, LoopTrace], trace_ids: Sequence[str]) -> Placement | None:
    """The placement (part -> machine) the loop's traces were rebuilt and compensated in (its
    reconstructions' ``placement`` / ``registration_job_id``; the first trace's stands for
    all: a loop places every trace alike), else None (the part's own frame)."""
    first = entries[trace_ids[0]] if trace_ids else None
    rec = ctx.job(first.reconstruct, kind="reconstruct", field="params.closed_loop_job_id") if first else None
    placed = PlacedParams.model_validate({k: (rec.params or {}).get(k) for k in ("placement", "registration_job_id")}
                                         if rec is not None else {})
    return placement_from(ctx, placed)


def measured_surface(ctx: JobContext, mesh: trimesh.Trimesh, entries: dict[str, LoopTrace], trace_ids: Sequence[str],
                     runs: Sequence[str], stations: Sequence[Sequence[float]], deviations: list[float],
                     placement: Placement | None = None) -> tuple[MeasuredSurface, FieldCheck | None]:
    """(the surface, the loop's checked field or None) in the loop's frame: ``mesh`` is the
    part's mesh already moved by ``placement`` (the loop's, :func:`loop_placement`), and
    ``stations`` (n, 2) mm are the probe stations' machine xy."""
    top = mesh_top_sampler(mesh)

    def nominal(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sample = top(xy)
        return sample.z, sample.grad

    first = entries[trace_ids[0]] if trace_ids else None
    rec = ctx.job(first.reconstruct, kind="reconstruct", field="params.closed_loop_job_id") if first else None
    plan = None
    if first is not None and len(runs) == 1:
        run = ctx.job(runs[0], kind="probe_run", field="params.closed_loop_job_id")
        plan = ctx.job(run.params["plan_job_id"], field="params.closed_loop_job_id")
    if rec is not None and plan is not None and ProbePlanResult.of(plan).field and rec.params.get("method") == "field":
        sigma = ((rec.result or {}).get("sigma") or {}).get("sigma_mm")
        check = run_field(ctx, runs[0], sigma, bool(rec.params.get("learn_prior", True)), list(trace_ids),
                          placement, trace_field="params.closed_loop_job_id")[0]
        posterior = check.fit.posterior

        def field(xy: np.ndarray, slope: np.ndarray, want_sd: bool) -> tuple[np.ndarray, np.ndarray | None]:
            mean, sd = np.empty(len(xy)), np.empty(len(xy))
            for i in range(0, len(xy), SD_CHUNK):
                sites = Sites(xy[i:i + SD_CHUNK], slope[i:i + SD_CHUNK])
                mean[i:i + SD_CHUNK] = posterior.mean(sites)
                if want_sd:
                    sd[i:i + SD_CHUNK] = posterior.sd(sites)
            return mean, sd if want_sd else None

        step = posterior.prior.wavelength_mm / SD_PER_WAVELENGTH
        return MeasuredSurface(nominal, field, check.coverage, step), check
    interpolated = deviation_field(np.array(stations), np.array(deviations))

    def between(xy: np.ndarray, _slope: np.ndarray, _sd: bool) -> tuple[np.ndarray, np.ndarray | None]:
        return interpolated(xy), None

    return MeasuredSurface(nominal, between), None
