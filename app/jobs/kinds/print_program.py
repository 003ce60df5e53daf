"""Job ``print``: stream an uploaded program or a job's G-code artifact to a machine.

Cancel ends the program after the commands in flight; pause/resume act on the machine.
When the link drops mid-program (or the server dies) the job becomes ``interrupted`` and
waits: ``POST /jobs/{id}/resume`` reconnects, takes the first command not known to be
executed (``Machine.resume_line``), re-homes and streams on from there
(``app.runtime.machine_queue``).  ``program_state`` in the job record shows where it stands.

Drift reference (``drift_reference``, default on): on a machine whose probe
calibration has a pad reading and whose profile has a reference pad, the probe (T0)
touches the pad right before streaming and the program's absolute Z is shifted by the
reading now minus the reading at calibration (:func:`app.gcode.shift.shift_z`): the Z the
machine drifted since the calibration the program's frame rests on.  The SHIFTED program is
what is streamed, recorded (``program``: its lines, commands and ``commands_sha256``, the
artifact's as ``source_program``) and, on a resume, rebuilt with the recorded shift, so the
executed stream and the resume point refer to what was really sent.  The program's own
``T<tool>`` line selects its tool again.  Machines without such a calibration: unchanged.
"""

from __future__ import annotations

import time

import numpy as np
from pydantic import Field, model_validator

from app.domain.errors import Cancelled, InvalidInput
from app.gcode.dispense_delays import with_dispense_delays
from app.gcode.placement import check_inside, profile_volume
from app.gcode.shift import shift_z
from app.jobs.calibration import current_calibration, machine_profile
from app.jobs.calibration_touch import travel_height
from app.jobs.gcode_meta import check_gcode, gcode_meta
from app.jobs.results.models import PrintResult
from app.machines.dispenser import machine_dispense
from app.machines.live import MachineFault, MachineUnavailable, hardware_errors, translate
from app.machines.materials import BY_NAME, MATERIALS, DispenseProfile
from app.runtime.context import JobContext
from app.runtime.machine_queue import (
    connected_machine,
    interrupt,
    machine_for_job,
    plan_eta,
    refuse_if_machine_busy,
    resume_point,
    resume_request,
    stopped_by_operator,
)
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind
from hardware.backend import Machine as LiveMachine
from hardware.errors import HardwareError, LinkError
from hardware.protocol import validate_program

PROGRESS_INTERVAL_S = 0.25
GCODE_MEDIA_TYPE = "text/x-gcode"
PAD_APPROACH_MM = 1.5   # the pad touch starts this far above the pad's nominal top (+ the ball radius)
PAD_OVERTRAVEL_MM = 1.5  # and may go this far below it (the nominal place is known to ~0.3 mm)
PAD_TOUCHES = 5          # averaged: one touch scatters by the probe's noise and pre-travel scatter
PAD_SPACING_MM = 0.5     # apart along x around the pad's nominal centre (as the qualification)


class PrintParams(JobParams):
    machine_id: str
    program_id: str | None = None
    job_id: str | None = None
    artifact: str | None = Field(None, description="artifact of job_id to print, e.g. print.gcode")
    dispense: DispenseProfile | None = Field(None, description="this print's dispense profile (default: the "
                                             "machine's profile.dispense; none: the program as written)")
    material: str | None = Field(None, max_length=80, description="this print's dispense profile: the machine's "
                                 "own profile of this material (profile.dispense_by_material), else the preset's of "
                                 "this name (GET /materials)")
    drift_reference: bool = Field(True, description="touch the reference pad with the probe first and shift the "
                                  "program's Z by the drift since the probe calibration (machines with a "
                                  "calibrated pad reading and a profile reference pad; others: no effect)")

    @model_validator(mode="after")
    def _one_source(self) -> PrintParams:
        if (self.program_id is None) == (self.job_id is None):
            raise ValueError("give exactly one of program_id or job_id (+ artifact)")
        if self.job_id is not None and not self.artifact:
            raise ValueError("artifact names the job's G-code artifact to print")
        if self.dispense is not None and self.material is not None:
            raise ValueError("give at most one of dispense or material")
        if self.material is not None and (BY_NAME.get(self.material) is None
                                          or BY_NAME[self.material].dispense is None):
            known = ", ".join(m.name for m in MATERIALS if m.dispense is not None)
            raise ValueError(f"material {self.material!r} is no dispensed material (known: {known})")
        return self


def _refuse_outside_travel(params: PrintParams, reads: JobReads, bounds: list | None, field: str) -> None:
    """A program whose moves leave the machine's ``profile.volume_mm`` is refused (real-parts)."""
    machine = reads.find_machine(params.machine_id)
    volume = profile_volume(machine.profile if machine else None, f"machine {params.machine_id}")
    if volume is not None and bounds is not None:
        check_inside(np.asarray(bounds, dtype=float), volume, field=field, what="the program")


def _check(params: PrintParams, reads: JobReads) -> None:
    refuse_if_machine_busy(params.machine_id, reads)
    if params.program_id is not None:
        program = reads.program(params.program_id, field="params.program_id")
        _refuse_outside_travel(params, reads, program.bounds, "params.program_id")
        return
    assert params.job_id is not None and params.artifact is not None  # PrintParams' rule
    artifact = reads.artifact(params.job_id, params.artifact)
    if artifact is None:
        raise InvalidInput(f"job {params.job_id!r} has no artifact {params.artifact!r}", field="params.artifact",
                           value=params.artifact)
    if artifact.media_type != GCODE_MEDIA_TYPE:
        raise InvalidInput(f"artifact {params.artifact!r} is {artifact.media_type}, not G-code",
                           field="params.artifact", value=params.artifact)
    _refuse_outside_travel(params, reads, (artifact.meta or {}).get("bounds"), "params.artifact")


def _references(params: PrintParams) -> list[tuple[str, str]]:
    refs = [("machine", params.machine_id)]
    if params.job_id:
        refs.append(("job", params.job_id))
    return refs


def _program_text(ctx: JobContext, params: PrintParams) -> str:
    if params.program_id is not None:
        with ctx.reads() as reads:
            program = reads.program(params.program_id, field="params.program_id")
        data = ctx.blob(program.sha256)
    else:
        assert params.job_id is not None and params.artifact is not None  # PrintParams' rule
        data = ctx.artifact_bytes(params.job_id, params.artifact)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InvalidInput("the artifact is not G-code text", field="params.artifact", value=params.artifact) from None
    check_gcode(text, field="params.artifact" if params.job_id else "params.program_id")
    return text


# one flat dispatch over cases; splitting it hides their order
@job_kind("print", PrintParams, queue="machine", check=_check, references=_references)
def run(ctx: JobContext, params: PrintParams) -> dict:  # noqa: C901
    """Stream a program to the machine with progress and cancel; a dropped link interrupts
    the job, and only an operator's resume continues it (from the first command not known
    executed, after re-homing)."""
    text = _program_text(ctx, params)
    resume = resume_request(ctx)
    dispense = resume.get("dispense") if resume is not None else _dispense(ctx, params)
    if dispense is not None:  # the delays are part of what is streamed (and resumed)
        text = _with_delays(text, dispense)
    lines = text.splitlines()
    source_meta = gcode_meta("\n".join(lines))
    total = len(validate_program(lines))
    state: dict = {"total": total, "executed": 0, "acked_line_no": None, "start_line": 0,
                   "resumes": (resume or {}).get("resumes", 0), "dispense": dispense}
    preamble: list[str] = []
    drift = (resume or {}).get("drift")
    reference = None  # interrupted before its pad touch ended: start afresh (nothing of the program ran)
    if resume is not None and drift is None and not resume.get("executed"):
        reference = _drift_reference(ctx, params)
    if resume is None or reference is not None:
        machine = connected_machine(ctx, params.machine_id)  # connect first: the machine shows it at once
        reference = reference or _drift_reference(ctx, params)
        if reference is not None:  # touched before anything of the program moved
            try:
                if resume is not None:  # interrupted during the touch: the position may be lost
                    machine.home()
                drift = _touch_pad(ctx, machine, params.machine_id, reference)
            except HardwareError as exc:  # a dropped link waits for an operator; a missed pad fails
                if isinstance(exc, LinkError) or stopped_by_operator(ctx, machine):
                    raise interrupt(ctx, machine, exc, state) from exc
                raise translate(exc) from exc
            state["drift"] = drift
            ctx.save_program_state(state)
        resume = None
    else:
        state.update({k: resume[k] for k in ("executed", "acked_line_no") if k in resume})
        machine = None
        try:  # a failure before the program moves anything leaves the job interrupted as it was
            machine = machine_for_job(ctx, params.machine_id, resume)
            with hardware_errors():
                state["start_line"], preamble = resume_point(machine, resume)
        except (HardwareError, MachineUnavailable, MachineFault) as exc:
            raise interrupt(ctx, machine, exc, state) from exc
        located = getattr(machine, "last_resume", None)
        state.update(executed=state["start_line"], acked_line_no=None, resumes=state["resumes"] + 1,
                     resume_preamble=preamble, resumed_from=state["start_line"],
                     resume_location=located.as_dict() if located is not None else
                     {"start": state["start_line"], "basis": "recorded count",
                      "detail": "no resume located on this machine: the first command not known done, from "
                                "its record of the lost program (or, in a new process, the job's count)"})
        if drift is not None:
            state["drift"] = drift
        ctx.save_program_state(state)
    meta = source_meta
    if drift is not None:  # what is streamed (and resumed) is the shifted program
        lines = shift_z(text, drift["dz_mm"]).text.splitlines()
        meta = gcode_meta("\n".join(lines))
    assert machine is not None  # connected above, or by machine_for_job
    last_report = 0.0
    cancelled = False

    def on_progress(executed: int, total: int) -> None:
        nonlocal last_report, cancelled
        now = time.monotonic()
        if now - last_report < PROGRESS_INTERVAL_S and executed < total:
            return
        last_report = now
        state.update(executed=executed, acked_line_no=machine.acked_line_no)
        ctx.save_program_state(dict(state))
        try:
            ctx.progress(executed / max(total, 1), f"{executed}/{total} commands")
        except Cancelled:
            if not cancelled:
                cancelled = True
                machine.cancel()

    plan_eta(machine, lines)
    with ctx.lease(params.machine_id):
        try:
            report = machine.stream(lines, on_progress=on_progress, start_line=state["start_line"])
        except HardwareError as exc:
            gap = machine.interrupted_program  # consistent (command, line number) pair
            if gap is not None:
                state.update(executed=gap.acked_index, acked_line_no=gap.acked_line_no)
            if isinstance(exc, LinkError) or stopped_by_operator(ctx, machine):
                raise interrupt(ctx, machine, exc, state) from exc
            raise translate(exc) from exc
    if cancelled or report.cancelled:
        why = "emergency stop; " if machine.estopped else ""
        raise Cancelled(f"{why}print cancelled after {report.executed} of {report.total} commands",
                        field="job_id", value=ctx.job_id)
    if resume is not None:  # the re-homing, then the modal state the skipped commands left
        preamble = preamble + list(machine.last_preamble)
    result = {"executed": report.executed, "total": report.total, "start_line": report.start_line,
              "resumes": state["resumes"], "resume_preamble": preamble,
              **({"resume_location": state["resume_location"]} if "resume_location" in state else {}),
              "elapsed_s": report.elapsed_s, "program": meta, "link": report.link_stats}
    if drift is not None:
        result |= {"source_program": source_meta, "drift": drift}
    if dispense is not None:
        result["dispense"] = dispense
    return PrintResult.written(result)


def _dispense(ctx: JobContext, params: PrintParams) -> dict | None:
    """The dispense profile this print applies, with the machine's on/off commands and
    dialect: the request's; for a material, the machine's own profile of it, else the
    preset's; else the machine's ``profile.dispense`` (or None)."""
    with ctx.reads() as reads:
        row = reads.machine(params.machine_id, field="params.machine_id")
        profile = machine_profile(row)
        dialect = row.dialect
    chosen: DispenseProfile | None
    if params.dispense is not None:
        chosen, source = params.dispense, "request"
    elif params.material in profile.dispense_by_material:
        chosen, source = profile.dispense_by_material[params.material], "machine's profile of the material"
    elif params.material is not None:
        chosen, source = BY_NAME[params.material].dispense, "material"
    else:
        chosen, source = profile.dispense, "machine profile"
    if chosen is None:
        return None
    on, off = machine_dispense(dialect)
    return {**chosen.model_dump(), "source": source, "dialect": dialect,
            "dispense_on": profile.dispense_on or on, "dispense_off": profile.dispense_off or off}


def _with_delays(text: str, dispense: dict) -> str:
    """``text`` with the profile's on/off dwells; counts them into ``dispense``."""
    delayed = with_dispense_delays(text, dispense["dispense_on"], dispense["dispense_off"],
                                   dispense["on_delay_ms"], dispense["off_delay_ms"], dispense["dialect"])
    dispense.update(on_dwells=delayed.on_dwells, off_dwells=delayed.off_dwells)
    return delayed.text


def _drift_reference(ctx: JobContext, params: PrintParams) -> dict | None:
    """What the pad touch needs (pad place, ball radius, the calibration's pad reading and
    its job, the travel height), or None when the drift reference does not apply."""
    if not params.drift_reference:
        return None
    with ctx.reads() as reads:
        row = reads.machine(params.machine_id, field="params.machine_id")
        profile = machine_profile(row)
        pad = profile.reference.pad if profile.reference is not None else None
        if pad is None:
            return None
        calibration = current_calibration(reads, params.machine_id)
    probe = calibration.probe
    if probe is None or probe.pad_reading_z_mm is None:
        return None
    return {"pad_mm": [float(v) for v in pad.centre_mm], "ball_radius_mm": float(probe.ball_radius_mm),
            "reference_z_mm": float(probe.pad_reading_z_mm), "probe_job_id": calibration.probe_job_id,
            "travel_z_mm": travel_height(profile, float(probe.ball_radius_mm)),
            "feed_mm_min": float(profile.probe_feed_mm_min)}


def _touch_pad(ctx: JobContext, machine: LiveMachine, machine_id: str, reference: dict) -> dict:
    """Touch the pad with the probe (T0) PAD_TOUCHES times around its nominal centre, straight
    down, back to the travel height: ``{dz_mm, pad_reading_z_mm (their mean), readings_z_mm,
    reference_z_mm, probe_job_id}`` (mm; dz = the reading now - the reading at calibration,
    the shift the program's Z gets)."""
    x0, y, z = reference["pad_mm"]
    travel, start = reference["travel_z_mm"], z + reference["ball_radius_mm"] + PAD_APPROACH_MM
    ctx.progress(0.0, "touching the reference pad (drift since calibration)")
    readings = []
    with ctx.lease(machine_id):
        machine.move(z=travel)
        machine.select_tool(0)
        for k in range(PAD_TOUCHES):
            x = x0 + (k - (PAD_TOUCHES - 1) / 2) * PAD_SPACING_MM
            machine.move(x=x, y=y)
            machine.move(z=start)
            hit = machine.probe_toward((x, y, start), (x, y, z - PAD_OVERTRAVEL_MM),
                                       feed_mm_min=reference["feed_mm_min"])
            readings.append(float(hit.z))
        machine.move(z=travel)
    reading = sum(readings) / len(readings)
    return {"dz_mm": reading - reference["reference_z_mm"], "pad_reading_z_mm": reading, "readings_z_mm": readings,
            "reference_z_mm": reference["reference_z_mm"], "probe_job_id": reference["probe_job_id"]}
