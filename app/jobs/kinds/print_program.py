"""Job ``print``: stream an uploaded program or a job's G-code artifact to a machine.

Cancel ends the program after the commands in flight; pause/resume act on the machine.
When the link drops mid-program (or the server dies) the job becomes ``interrupted`` and
waits: ``POST /jobs/{id}/resume`` reconnects, takes the first command not known to be
executed (``Machine.resume_line``), re-homes and streams on from there
(``app.jobs.machine_jobs``).  ``program_state`` in the job record shows where it stands.
"""

from __future__ import annotations

import time

import numpy as np
from pydantic import Field, model_validator
from sqlmodel import Session, select

from app.errors import Cancelled, InvalidInput
from app.jobs.context import JobContext
from app.jobs.gcode_meta import check_gcode, gcode_meta
from app.jobs.machine_jobs import (connected_machine, interrupt, machine_for_job, refuse_if_machine_busy, resume_point,
                                   resume_request, stopped_by_operator)
from app.jobs.registry import JobParams, job_kind
from app.gcode.placement import check_inside, profile_volume
from app.machines import MachineFault, MachineUnavailable, hardware_errors, translate
from app.models import Artifact, Machine, Program
from app.records import get_or_404
from hardware.errors import HardwareError, LinkError
from hardware.protocol import validate_program

PROGRESS_INTERVAL_S = 0.25
GCODE_MEDIA_TYPE = "text/x-gcode"


class PrintParams(JobParams):
    machine_id: str
    program_id: str | None = None
    job_id: str | None = None
    artifact: str | None = Field(None, description="artifact of job_id to print, e.g. print.gcode")

    @model_validator(mode="after")
    def _one_source(self) -> "PrintParams":
        if (self.program_id is None) == (self.job_id is None):
            raise ValueError("give exactly one of program_id or job_id (+ artifact)")
        if self.job_id is not None and not self.artifact:
            raise ValueError("artifact names the job's G-code artifact to print")
        return self


def _refuse_outside_travel(params: PrintParams, session: Session, bounds: list | None, field: str) -> None:
    """A program whose moves leave the machine's ``profile.volume_mm`` is refused (real-parts)."""
    machine = session.get(Machine, params.machine_id)
    volume = profile_volume(machine.profile if machine else None, f"machine {params.machine_id}")
    if volume is not None and bounds is not None:
        check_inside(np.asarray(bounds, dtype=float), volume, field=field, what="the program")


def _check(params: PrintParams, session: Session) -> None:
    refuse_if_machine_busy(params.machine_id, session)
    if params.program_id is not None:
        program = get_or_404(session, Program, params.program_id, field="params.program_id")
        _refuse_outside_travel(params, session, program.bounds, "params.program_id")
        return
    artifact = session.exec(select(Artifact).where(Artifact.job_id == params.job_id,
                                                   Artifact.name == params.artifact)).first()
    if artifact is None:
        raise InvalidInput(f"job {params.job_id!r} has no artifact {params.artifact!r}", field="params.artifact",
                           value=params.artifact)
    if artifact.media_type != GCODE_MEDIA_TYPE:
        raise InvalidInput(f"artifact {params.artifact!r} is {artifact.media_type}, not G-code",
                           field="params.artifact", value=params.artifact)
    _refuse_outside_travel(params, session, (artifact.meta or {}).get("bounds"), "params.artifact")


def _references(params: PrintParams) -> list[tuple[str, str]]:
    refs = [("machine", params.machine_id)]
    if params.job_id:
        refs.append(("job", params.job_id))
    return refs


def _program_text(ctx: JobContext, params: PrintParams) -> str:
    if params.program_id is not None:
        with ctx.session() as session:
            program = get_or_404(session, Program, params.program_id, field="params.program_id")
        data = ctx.runtime.blobs.read(program.sha256)
    else:
        data = ctx.artifact_bytes(params.job_id, params.artifact)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InvalidInput("the artifact is not G-code text", field="params.artifact", value=params.artifact) from None
    check_gcode(text, field="params.artifact" if params.job_id else "params.program_id")
    return text


@job_kind("print", PrintParams, queue="machine", check=_check, references=_references)
def run(ctx: JobContext, params: PrintParams) -> dict:
    """Stream a program to the machine with progress and cancel; a dropped link interrupts
    the job, and only an operator's resume continues it (from the first command not known
    executed, after re-homing)."""
    lines = _program_text(ctx, params).splitlines()
    meta = gcode_meta("\n".join(lines))
    resume = resume_request(ctx)
    total = len(validate_program(lines))
    state: dict = {"total": total, "executed": 0, "acked_line_no": None, "start_line": 0,
                   "resumes": (resume or {}).get("resumes", 0)}
    preamble: list[str] = []
    if resume is None:
        machine = connected_machine(ctx, params.machine_id)
    else:
        state.update({k: resume[k] for k in ("executed", "acked_line_no") if k in resume})
        machine = None
        try:  # a failure before the program moves anything leaves the job interrupted as it was
            machine = machine_for_job(ctx, params.machine_id, resume)
            with hardware_errors():
                state["start_line"], preamble = resume_point(machine, resume)
        except (HardwareError, MachineUnavailable, MachineFault) as exc:
            raise interrupt(ctx, machine, exc, state) from exc
        state.update(executed=state["start_line"], acked_line_no=None, resumes=state["resumes"] + 1,
                     resume_preamble=preamble, resumed_from=state["start_line"])
        ctx.runtime.store.save_program_state(ctx.claim, state)
    ctx.runtime.machines.running_job[params.machine_id] = ctx.job_id
    last_report = 0.0
    cancelled = False

    def on_progress(executed: int, total: int) -> None:
        nonlocal last_report, cancelled
        now = time.monotonic()
        if now - last_report < PROGRESS_INTERVAL_S and executed < total:
            return
        last_report = now
        state.update(executed=executed, acked_line_no=machine.acked_line_no)
        ctx.runtime.store.save_program_state(ctx.claim, dict(state))
        try:
            ctx.progress(executed / max(total, 1), f"{executed}/{total} commands")
        except Cancelled:
            if not cancelled:
                cancelled = True
                machine.cancel()

    try:
        report = machine.stream(lines, on_progress=on_progress, start_line=state["start_line"])
    except HardwareError as exc:
        gap = machine.interrupted_program  # consistent (command, line number) pair
        if gap is not None:
            state.update(executed=gap.acked_index, acked_line_no=gap.acked_line_no)
        if isinstance(exc, LinkError) or stopped_by_operator(ctx, machine):
            raise interrupt(ctx, machine, exc, state) from exc
        raise translate(exc) from exc
    finally:
        ctx.runtime.machines.running_job.pop(params.machine_id, None)
    if cancelled or report.cancelled:
        why = "emergency stop; " if machine.estopped else ""
        raise Cancelled(f"{why}print cancelled after {report.executed} of {report.total} commands",
                        field="job_id", value=ctx.job_id)
    if resume is not None:  # the re-homing, then the modal state the skipped commands left
        preamble = preamble + list(machine.last_preamble)
    return {"executed": report.executed, "total": report.total, "start_line": report.start_line,
            "resumes": state["resumes"], "resume_preamble": preamble,
            "elapsed_s": report.elapsed_s, "program": meta, "link": report.link_stats}
