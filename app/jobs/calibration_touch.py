"""Executing planned calibration touches on a machine (shared by ``calibrate_probe`` and
``calibrate_nozzle``): select each touch's tool, travel at the safe height, go down to the
touch's start, probe toward its target, record the reading (the carriage position at the
trigger, mm).  A ``local`` touch right after one of its kind and tool hops there instead
(``Touch.local``: up to the start's height, across, down; no trip to the travel height).  Ends retracted with the probe
(T0) selected, also when a touch fails.

Recovery follows ``probe_run``: a dropped link interrupts the job with the readings so far
in ``program_state``; an operator's resume re-homes and touches the interrupted one again
(a touch is idempotent).  Nothing moves without the operator-submitted job.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from app.calibration import Touch, hops
from app.calibration.nozzle import pad_grid
from app.calibration.qualify import PAD_SPACING_MM
from app.domain.errors import ConformaError, InvalidInput
from app.machines.live import hardware_errors, translate
from app.runtime.context import JobContext
from app.runtime.machine_queue import interrupt, rehomed_machine, resume_request, stopped_by_operator
from hardware.backend import Machine
from hardware.errors import HardwareError, LinkError

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


def check_pad_room(size_mm: float, touches: int, *, grid: bool = False) -> None:
    """422 (``params.pad_touches``) when the pad spots (0.5 mm apart along x, or on the 2-D
    grid of ``app.calibration.nozzle.pad_grid``) do not fit on the pad with ``OFFSET_DOUBT_MM``
    to spare on each side."""
    cols, rows = pad_grid(touches) if grid else (touches, 1)
    span = (max(cols, rows) - 1) * PAD_SPACING_MM
    if span + 2 * OFFSET_DOUBT_MM > size_mm:
        shape = f"a {cols} x {rows} grid" if grid else "a row"
        raise InvalidInput(f"{touches} pad touches ({shape}) span {span:.1f} mm: too many for a {size_mm:g} mm pad "
                           f"({OFFSET_DOUBT_MM:g} mm to spare on each side)", field="params.pad_touches", value=touches)


class TouchRun:
    """The touching part of one calibration job, in named stages (e.g. "locate", then
    "qualify"): ``with TouchRun(...) as run: readings = run.touch(steps, "qualify", label)``.
    Readings of every stage are kept in ``program_state`` so that a resumed job skips the
    touches it already made; the job ends with ``run.park()`` (travel height, T0), a failed
    touch parks by itself.  The block marks the machine's running job."""

    def __init__(self, ctx: JobContext, machine_id: str, *, travel_z: float, feed_mm_min: float) -> None:
        self.ctx, self.machine_id, self.travel_z, self.feed = ctx, machine_id, travel_z, feed_mm_min
        resume = resume_request(ctx)
        self.state: dict[str, Any] = {"total": 0, "executed": 0, "stages": dict((resume or {}).get("stages", {})),
                                      "resumes": (resume or {}).get("resumes", 0)}
        self.machine = rehomed_machine(ctx, machine_id, resume, self.state)
        try:  # where the touches start from: the origin of the touches' estimated machine times
            with hardware_errors():
                self.origin = tuple(float(v) for v in self.machine.position())
        except ConformaError as exc:
            raise interrupt(ctx, self.machine, exc.__cause__ or exc, self.state) from exc
        self.tool: int | None = None  # unknown after a connect or a resume: select before the first touch
        # the touch just made and where it left the carriage (its start): a ``local`` touch of its kind hops from there
        self.previous: Step | None = None
        self.here: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __enter__(self) -> TouchRun:
        self._lease = self.ctx.lease(self.machine_id)
        self._lease.__enter__()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: Any) -> None:
        self._lease.__exit__(kind, exc, tb)

    def touch(self, steps: Sequence[Step], stage: str, label: str, span: tuple[float, float] = (0.05, 0.9),
              ) -> list[list[float]]:
        """Touch ``steps`` in order (skipping those a resumed job already made); the
        readings (n, 3) mm, carriage coordinates."""
        machine, state = self.machine, self.state
        readings: list[list[float]] = [list(r) for r in state["stages"].get(stage, [])]
        state["stages"][stage] = readings
        state["total"] = sum(len(v) for k, v in state["stages"].items() if k != stage) + len(steps)
        try:
            for index in range(len(readings), len(steps)):
                step = steps[index]
                if machine.link_lost:  # the link dropped after the previous touch
                    raise LinkError("link lost", field="port")
                x, y, z = (float(v) for v in step.touch.start_mm)
                previous = self.previous
                if previous is not None and step.tool == previous.tool and hops(previous.touch, step.touch):
                    machine.move(z=max(self.here[2], z))   # a hop near the artifact (the planner's word)
                else:
                    machine.move(z=self.travel_z)
                if step.tool != self.tool:
                    machine.select_tool(step.tool)
                    self.tool = step.tool
                machine.move(x=x, y=y)
                machine.move(z=z)
                tx, ty, tz = (float(v) for v in step.touch.target_mm)
                self.previous = None             # until the touch is made: an error leaves the position unknown
                hit = machine.probe_toward((x, y, z), (tx, ty, tz), feed_mm_min=self.feed)
                self.previous, self.here = step, (x, y, z)   # probe_toward ends back at the start
                readings.append([float(hit.x), float(hit.y), float(hit.z)])
                state["executed"] = sum(len(v) for v in state["stages"].values())
                self.ctx.save_program_state(state)
                self.ctx.progress(span[0] + (span[1] - span[0]) * len(readings) / len(steps),
                                  f"{label}: touch {len(readings)}/{len(steps)} ({step.touch.kind}, T{step.tool})")
        except LinkError as exc:  # a touch is idempotent: a resume touches this one again
            raise interrupt(self.ctx, machine, exc, state) from exc
        except HardwareError as exc:
            if stopped_by_operator(self.ctx, machine):
                raise interrupt(self.ctx, machine, exc, state) from exc
            _retract_quietly(machine, self.travel_z)
            raise translate(exc) from exc
        return readings

    def park(self) -> None:
        """Up to the travel height with the probe (T0) selected (the end of every job)."""
        self.previous = None
        try:
            with hardware_errors():
                _park(self.machine, self.travel_z)
        except ConformaError as exc:
            if isinstance(exc.__cause__, LinkError) or stopped_by_operator(self.ctx, self.machine):
                raise interrupt(self.ctx, self.machine, exc.__cause__ or exc, self.state) from exc
            raise


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
