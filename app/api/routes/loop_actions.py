"""A closed loop's pause points over HTTP: continue, accept, add stations (abandon and cancel
are :mod:`app.api.routes.jobs`'s).  Each records the operator's decision and queues the loop
again (:func:`app.jobs.loop_gates.decide`); nothing moves before that."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from pydantic import Field

from app.api.deps import Operator, RuntimeDep, SessionDep
from app.api.routes.jobs import load_job_out
from app.api.schemas import JobOut, Strict
from app.jobs.loop_gates import decide

router = APIRouter(prefix="/api/v1/jobs", tags=["jobs"])
_409: dict[int | str, dict[str, Any]] = {409: {"description": "the job is not a closed loop where this action applies "
                                                              "(the detail says why)"}}


class AddStations(Strict):
    """The start of the added round's prior (default: the prior the loop's field learned,
    its verdict's ``suggested_probe``) and its touch budget (default: the loop's)."""

    deviation_amplitude_mm: float | None = Field(None, gt=0, le=10)
    deviation_wavelength_mm: float | None = Field(None, gt=0, le=10_000)
    touch_budget: int | None = Field(None, ge=1, le=100_000)


@router.post("/{job_id}/continue", status_code=202, dependencies=[Operator], responses=_409)
def continue_loop(job_id: str, runtime: RuntimeDep, session: SessionDep) -> JobOut:
    """Let a ``waiting`` closed loop go on past its pause point (refused, 409, where its
    verification failed: accept it or add stations)."""
    decide(runtime, job_id, "continue")
    return load_job_out(session, job_id)


@router.post("/{job_id}/accept", status_code=202, dependencies=[Operator], responses=_409)
def accept_loop(job_id: str, runtime: RuntimeDep, session: SessionDep) -> JobOut:
    """Accept a closed loop whose verification failed (``waiting`` at ``verified``, or ended
    ``needs_attention``): it goes on (prints, with ``print``) and its verdict records the
    acceptance."""
    decide(runtime, job_id, "accept")
    return load_job_out(session, job_id)


@router.post("/{job_id}/add-stations", status_code=202, dependencies=[Operator], responses=_409)
def add_stations(job_id: str, runtime: RuntimeDep, session: SessionDep, body: AddStations | None = None) -> JobOut:
    """Plan one more round of stations from a field loop's run so far (``waiting`` at
    ``verified``, or ended ``needs_attention``), probe them, refit and verify again."""
    decide(runtime, job_id, "add_stations", (body or AddStations()).model_dump())
    return load_job_out(session, job_id)
