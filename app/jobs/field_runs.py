"""The touches of a field plan's probe run, with the stations an earlier run touched.

A sequential field plan (``probe_plan`` with ``fixed_run_job_id``) lists every station the
field is fitted from: the ones earlier runs touched (``from_run``: that probe run's id,
``run_index``: the point's index among that run's points) and its own, which its probe run
touches (in order, after the earlier ones).  :func:`field_touches` puts the measured points
of all of them in the plan's station order, for the reconstruction and for the next round's
learning.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.jobs.context import JobContext
from app.jobs.results import ProbePlanResult, ProbeRunResult
from app.models import Job


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
