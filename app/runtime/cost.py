"""Cost estimates at submission: hopeless parameters are a 422, not an out-of-memory worker.

A kind may register ``estimate(params, reads) -> Cost``: its predicted peak memory (MiB,
above the worker's baseline) and wall-clock time (s) from the parameters alone, with the
parameter that drives the cost.  The models are simple formulas in each kind's module
(how many cells, points, unknowns or path segments a job allocates), with constants
calibrated by measurement (``tests/bench/test_bench_compute_limits.py`` prints the measured
peaks against the predictions).  :func:`check_cost` refuses a job whose estimate exceeds
the compute job limits (``CONFORMA_JOB_MEMORY_MB``, ``CONFORMA_JOB_TIME_S``): the job would
only be killed at the limit, after holding a worker for nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from app.domain.errors import InvalidInput
from app.platform.config import Settings

MIB = 2**20


@dataclass(frozen=True)
class Cost:
    """A job's predicted peak memory (MiB above the worker's baseline) and time (s).

    field: the dotted parameter that drives the cost (``params.grid``); value: its value;
    basis: what was counted (e.g. "40000 grid points, 1600 unknowns"), for the message.
    """

    memory_mb: float
    time_s: float
    field: str
    value: Any
    basis: str


def check_cost(kind: Any, params: Any, reads: Any, settings: Settings) -> Cost | None:
    """Raise :class:`InvalidInput` (naming the driving parameter) when ``kind``'s estimate of
    ``params`` exceeds the job memory or time limit; returns the estimate (None without one)."""
    if kind.estimate is None:
        return None
    cost = kind.estimate(params, reads)
    if cost is None:
        return None
    if cost.memory_mb > settings.job_memory_mb:
        raise InvalidInput(
            f"{cost.field} {cost.value!r}: the job would need about {cost.memory_mb:,.0f} MiB ({cost.basis}), "
            f"more than the compute job limit of {settings.job_memory_mb:,.0f} MiB (CONFORMA_JOB_MEMORY_MB)",
            field=cost.field, value=cost.value)
    if cost.time_s > settings.job_time_s:
        raise InvalidInput(
            f"{cost.field} {cost.value!r}: the job would run for about {cost.time_s:,.0f} s ({cost.basis}), "
            f"longer than the compute job limit of {settings.job_time_s:,.0f} s (CONFORMA_JOB_TIME_S)",
            field=cost.field, value=cost.value)
    return cost


def largest(*costs: Cost) -> Cost:
    """The cost with the largest memory (ties: time); for kinds with several stages."""
    return max(costs, key=lambda c: (c.memory_mb, c.time_s))
