"""A scan's passes driven on the machine, each stored as it is made, and resumed after an interruption.

Each finished pass is stored at once as the artifact ``pass.<k>.npz`` (``carriage`` (n, 3)
mm where each reading was exposed, ``values`` (n,) mm, NaN: no value, ``stamps`` (n,) s; see
:class:`app.jobs.sensor_runs.ScannedPass`) and the job's ``program_state`` records how many passes are done
(``passes_done``, with ``total``, ``executed`` and the plan's ``plan_sha256``).  When the
machine's or the sensor's link drops, the job becomes ``interrupted`` and waits for an
operator (:func:`app.runtime.machine_queue.interrupt`; nothing moves); an operator's resume
re-homes the machine, keeps every stored pass and continues at the first pass not stored
(the pass the link dropped in is scanned again whole: a pass is idempotent), hopping to it
at the travel height.  A resume of a different plan (parameters or part changed) starts
again from the first pass.  Other hardware errors fail the job (it stops; the operator runs
it again).
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from app.jobs.sensor_runs import ScannedPass, open_scanner
from app.machines.live import hardware_errors
from app.runtime.context import JobContext
from app.runtime.machine_queue import interrupt, rehomed_machine, resume_request, stopped_by_operator
from hardware.errors import HardwareError, LinkError

PASS_MEDIA_TYPE = "application/octet-stream"


def pass_name(k: int) -> str:
    return f"pass.{k:05d}.npz"


def plan_sha256(waypoints: Sequence[np.ndarray], speed_mm_s: float) -> str:
    """What identifies a plan's passes (their carriage waypoints and speed)."""
    digest = hashlib.sha256(np.float64(speed_mm_s).tobytes())
    for w in waypoints:
        digest.update(np.ascontiguousarray(w, dtype=float).tobytes())
    return digest.hexdigest()


def _npz(scanned: ScannedPass) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, carriage=scanned.carriage, values=scanned.values, stamps=scanned.stamps)
    return buf.getvalue()


def _stored(data: bytes) -> ScannedPass:
    with np.load(io.BytesIO(data)) as npz:
        return ScannedPass(npz["carriage"], npz["values"], npz["stamps"])


def scan_passes(ctx: JobContext, machine_id: str, sensor_port: str | None, rate_hz: float,
                waypoints: Sequence[np.ndarray], hops: Sequence[bool], speed_mm_s: float, travel_z: float,
                time_offset_s: float, probe_tool: bool = False) -> tuple[list[ScannedPass], Any, dict]:
    """Drive every pass (carriage waypoints (m, 3) each; ``hops``: go up to ``travel_z``
    before it) with the machine leased, the probe (T0: the carriage frame the sensor's offset is
    in) selected first with ``probe_tool``, the sensor read as the machine's port says
    (:func:`app.jobs.sensor_runs.open_scanner`; ``time_offset_s`` the calibrated one); (each
    pass, the machine, the state).
    Raises ``Interrupted`` after a dropped link (the job waits), ``Cancelled`` when an
    operator stopped the machine, a translated hardware error otherwise."""
    key = plan_sha256(waypoints, speed_mm_s)
    resume = resume_request(ctx)
    done = int(resume.get("passes_done", 0)) if resume is not None and resume.get("plan_sha256") == key else 0
    state: dict[str, Any] = {"total": len(waypoints), "executed": done, "passes_done": done, "plan_sha256": key,
                             "resumes": int((resume or {}).get("resumes", 0))}
    machine = rehomed_machine(ctx, machine_id, resume, state)
    passes = [_stored(ctx.artifact_bytes(ctx.job_id, pass_name(k))) for k in range(done)]
    with ctx.lease(machine_id), interrupting(ctx, machine, state):
        if probe_tool and done < len(waypoints):
            machine.select_tool(0)
        scanner = open_scanner(machine, sensor_port, rate_hz)
        try:
            for k in range(done, len(waypoints)):
                hop = bool(hops[k]) or k == done  # after a resume's homing: to the pass at the travel height
                one = scanner.run(waypoints[k], speed_mm_s, travel_z if hop else None, time_offset_s)
                ctx.artifact(pass_name(k), _npz(one), PASS_MEDIA_TYPE, {"samples": len(one.values)})
                passes.append(one)
                state.update(passes_done=k + 1, executed=k + 1)
                ctx.save_program_state(state)
                ctx.progress(0.8 * (k + 1) / len(waypoints), f"scanned {k + 1}/{len(waypoints)} passes")
        finally:
            scanner.close()
    return passes, machine, state


@contextmanager
def interrupting(ctx: JobContext, machine: Any, state: dict[str, Any]) -> Iterator[None]:
    """Machine work of a scan: a dropped link (or an operator's stop) interrupts the job with
    ``state`` (it waits for an operator), another hardware error is translated (the job fails)."""
    try:
        yield
    except LinkError as exc:
        raise interrupt(ctx, machine, exc, state) from exc
    except HardwareError as exc:
        if stopped_by_operator(ctx, machine):
            raise interrupt(ctx, machine, exc, state) from exc
        with hardware_errors():
            raise
