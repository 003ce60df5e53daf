"""Where a connected machine's head is now, for the 3-D view's head on the path.

A mock machine reports its simulated world's position (the truth the mock moves); another
machine is asked only while idle (``M114`` / the status report would queue behind a
streaming program), so while it prints its position reads as unknown here.  ``line`` is
the running program's executed line count (:attr:`hardware.machine.Machine.progress`).
Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hardware.errors import HardwareError


@dataclass(frozen=True)
class Head:
    """position_mm (3,) or None when unknown; state of the machine; line / total of the running
    program (None when none runs); job_id: the job driving it; source: where the position came from."""

    position_mm: tuple[float, float, float] | None
    state: str
    line: int | None
    total: int | None
    job_id: str | None
    source: str


def head_of(runtime: Any, machine_id: str) -> Head:
    """The head of machine ``machine_id`` (``runtime.machines``' live machine; disconnected
    when it has none)."""
    live = runtime.machines.get(machine_id)
    if live is None:
        return Head(None, "disconnected", None, None, None, "not connected")
    state = live.state
    progress = live.progress if state in ("printing", "paused") else None
    line, total = progress if progress is not None else (None, None)
    job_id = runtime.machines.running_job.get(machine_id)
    world = runtime.machines.world_by_id(machine_id)
    if state == "error":
        return Head(None, state, line, total, job_id, "unknown after a stop or a fault: connect, then home")
    if world is not None:
        x, y, z = (float(v) for v in list(world.position)[:3])
        return Head((x, y, z), state, line, total, job_id, "the mock machine's simulated position")
    if state != "idle":
        return Head(None, state, line, total, job_id, "the controller is asked only while idle")
    try:
        x, y, z = live.position()
    except HardwareError as exc:
        return Head(None, state, line, total, job_id, f"no position: {exc}")
    return Head((float(x), float(y), float(z)), state, line, total, job_id, "the controller's report")
