"""Executing planned calibration touches on a machine (shared by ``calibrate_probe`` and
``calibrate_nozzle``): select each touch's tool, travel at the safe height, go down to the
touch's start, probe toward its target, record the reading (the carriage position at the
trigger, mm).  Ends retracted with the probe (T0) selected, also when a touch fails.

Recovery follows ``probe_run``: a dropped link interrupts the job with the readings so far
in ``program_state``; an operator's resume re-homes and touches the interrupted one again
(a touch is idempotent).  Nothing moves without the operator-submitted job.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from app.calibration import Touch
from app.jobs.context import JobContext
from app.jobs.machine_jobs import (interrupt, rehomed_machine, resume_request, stopped_by_operator)
from app.machines import translate
from hardware.errors import HardwareError, LinkError
from hardware.machine import Machine

MARGIN_MM = 2.0          # travel this far above the highest artifact (plus the tools' hang)
OFFSET_DOUBT_MM = 1.0    # a nominal nozzle offset may be this far off (the profile says +-0.2 mm)


@dataclass(frozen=True)
class Step:
    """One planned touch and the tool that makes it (0 = the probe)."""

    touch: Touch
    tool: int


def travel_height(profile: Any, ball_radius_mm: float) -> float:
    """Carriage Z for travel (mm): the profile's clearance (the probe's safe height) raised
    by how far the lowest nozzle hangs below the probe (nominal offset + 1 mm of doubt),
    and high enough that ball and tips pass above the reference pad and sphere.
    ``profile``: :class:`app.api.machine_schemas.Profile`."""
    nozzles = profile.tools.nozzles if profile.tools is not None else []
    hang = max([0.0] + [-float(n.offset_mm[2]) + OFFSET_DOUBT_MM for n in nozzles])
    heights = [float(profile.clearance_z) + hang]
    reference = profile.reference
    if reference is not None and reference.pad is not None:
        heights.append(float(reference.pad.centre_mm[2]) + MARGIN_MM + max(ball_radius_mm, hang))
    if reference is not None and reference.sphere is not None:
        top = float(reference.sphere.centre_mm[2]) + float(reference.sphere.diameter_mm) / 2
        heights.append(top + MARGIN_MM + max(ball_radius_mm, hang))
    return max(heights)


def run_steps(ctx: JobContext, machine_id: str, steps: Sequence[Step], *, travel_z: float,
              feed_mm_min: float, label: str) -> list[list[float]]:
    """Touch every step in order; the readings (n, 3) mm, carriage coordinates."""
    resume = resume_request(ctx)
    readings: list[list[float]] = [list(r) for r in (resume or {}).get("readings", [])]
    state: dict[str, Any] = {"total": len(steps), "executed": len(readings), "readings": readings,
                             "resumes": (resume or {}).get("resumes", 0)}
    machine = rehomed_machine(ctx, machine_id, resume, state)
    machines = ctx.runtime.machines
    machines.running_job[machine_id] = ctx.job_id
    tool: int | None = None  # unknown after a connect or a resume: select before the first touch
    try:
        try:
            for index in range(len(readings), len(steps)):
                step = steps[index]
                if machine.link_lost:  # the link dropped after the previous touch
                    raise LinkError("link lost", field="port")
                machine.move(z=travel_z)
                if step.tool != tool:
                    machine.select_tool(step.tool)
                    tool = step.tool
                x, y, z = (float(v) for v in step.touch.start_mm)
                machine.move(x=x, y=y)
                machine.move(z=z)
                hit = machine.probe_toward((x, y, z), tuple(float(v) for v in step.touch.target_mm),
                                           feed_mm_min=feed_mm_min)
                readings.append([float(hit.x), float(hit.y), float(hit.z)])
                state["executed"] = len(readings)
                ctx.runtime.store.save_program_state(ctx.claim, state)
                ctx.progress(0.05 + 0.85 * len(readings) / len(steps),
                             f"{label}: touch {len(readings)}/{len(steps)} ({step.touch.kind}, T{step.tool})")
            _park(machine, travel_z)
        except LinkError as exc:  # a touch is idempotent: a resume touches this one again
            raise interrupt(ctx, machine, exc, state) from exc
        except HardwareError as exc:
            if stopped_by_operator(ctx, machine):
                raise interrupt(ctx, machine, exc, state) from exc
            _retract_quietly(machine, travel_z)
            raise translate(exc) from exc
    finally:
        machines.running_job.pop(machine_id, None)
    return readings


def _park(machine: Machine, travel_z: float) -> None:
    """Up to the travel height, then the probe (T0) selected."""
    machine.move(z=travel_z)
    machine.select_tool(0)


def _retract_quietly(machine: Machine, travel_z: float) -> None:
    """After a failed touch (the machine still answers): leave it retracted at T0."""
    try:
        _park(machine, travel_z)
    except HardwareError:
        pass  # the job fails with the touch's error; the machine's state says the rest
