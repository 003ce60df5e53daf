"""Machines: register, connect, status, pause/resume, emergency stop, print; manual
control (home, jog, a console line) and removal.

The API process owns the serial ports (and runs one execution thread per machine), so
these endpoints act on the live connection directly.  Nothing here waits behind a
running program: pause/resume go straight to the machine; stop is an async route with
its own threads and its own write to the link (out of band, never queued).
"""

from __future__ import annotations

import asyncio
import logging
import time
from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Request, Response
from sqlalchemy import delete
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, col, select

from app.api import idempotency
from app.api.deps import Operator, RuntimeDep, SessionDep, Viewer
from app.api.machine_schemas import (
    MAX_MATERIAL_PROFILES,
    CalibrationOut,
    ConsoleOut,
    ConsoleRequest,
    ControllerOut,
    JogRequest,
    MachineCreate,
    MachineOut,
    MachineUpdate,
    MockSettings,
    PrintRequest,
    ProgramState,
    StopOut,
    UnlockRequest,
)
from app.api.routes.jobs import load_job_out
from app.api.schemas import JobOut, Page
from app.domain.errors import Conflict, InvalidInput, NotFound
from app.jobs.calibration import calibration_summary, current_calibration, machine_profile
from app.machines.dispenser import machine_dispense
from app.machines.live import hardware_errors, port_key, port_owner, translate
from app.machines.materials import BY_NAME, MATERIALS
from app.platform.db import lock_for_delete
from app.platform.lookup import get_or_404
from app.platform.models import TERMINAL_STATES, Job, JobReference, Machine, Part, new_id, utcnow
from app.runtime.engine import Runtime
from app.runtime.machine_queue import holding_message
from app.runtime.reads import JobReads
from hardware.errors import HardwareError, InvalidConfig
from hardware.mock import parse_mock_options
from hardware.port_url import PortUrl

router = APIRouter(prefix="/api/v1/machines", tags=["machines"])
log = logging.getLogger("conforma.api.machines")


def machine_out(runtime: Runtime, row: Machine) -> MachineOut:
    live = runtime.machines.get(row.id)
    state = live.state if live is not None else "disconnected"
    position = None
    program = None
    world = runtime.machines.world(row)
    if state == "error":
        pass  # after an emergency stop or a fault the controller's position is not known: home first
    elif world is not None:
        position = list(world.position)
    elif live is not None and state == "idle":
        try:  # a read of the record never fails on the controller's answer: the position is unknown
            position = list(live.position())
        except HardwareError as exc:
            log.info("machine %s: no position (%s)", row.id, exc)
    holder = runtime.store.holding_job(row.id)
    if live is not None and live.progress is not None and state in ("printing", "paused"):
        executed, total = live.progress
        clock = live.clock
        started = clock.started_at
        program = ProgramState(job_id=runtime.machines.running_job.get(row.id) or (holder or {}).get("id"),
                               line=executed, total=total, state=state, elapsed_s=clock.elapsed_s(),
                               eta_s=clock.eta_s(executed, total),
                               started_at=datetime.fromtimestamp(started, UTC) if started else None)
    elif holder is not None and holder["status"] == "interrupted":
        program = interrupted_program(row.id, holder, live.program_status() if live is not None else None)
    mock = None
    if row.mock is not None:
        mock = dict(row.mock)
        if world is not None:
            mock.update(executed_commands=world.executed_count, executed_sha256=world.executed_sha256,
                        deposited_moves=len(world.deposition_log))
    known = getattr(live, "controller", None) if live is not None and state != "disconnected" else None
    homed = None
    if live is not None and state != "disconnected":
        homed = live.homed and state != "error" and not (known is not None and known.state == "Alarm")
    return MachineOut(**row.model_dump(exclude={"mock"}), mock=mock, state=state, position=position, homed=homed,
                      program=program, held_by=holder["id"] if holder is not None else None,
                      outputs=getattr(live, "outputs", None) if state != "disconnected" else None,
                      firmware=live.identity.firmware if live is not None and live.identity else None,
                      controller=ControllerOut(**known.as_dict()) if known is not None else None)


def interrupted_program(machine_id: str, job: dict, live: dict | None) -> ProgramState:
    """The interrupted program of ``job`` (which holds the machine): where it stopped from the
    live machine when this process ran it (``Machine.program_status``), else from the job's
    recorded ``program_state`` (a restarted server)."""
    recorded = job.get("program_state") or {}
    live = live if live is not None and live.get("state") == "interrupted" else {}
    line = live.get("line", recorded.get("executed"))
    total = live.get("total", recorded.get("total"))
    return ProgramState(job_id=job["id"], line=line, total=total, state="interrupted",
                        resume_line=live.get("resume_line"), waits="resume or abandon",
                        message=holding_message(machine_id,
                                                {**job, "program_state": {"executed": line, "total": total}}))


@router.post("", status_code=201, dependencies=[Operator])
def register_machine(body: MachineCreate, runtime: RuntimeDep, session: SessionDep, request: Request,
                     response: Response, idempotency_key: idempotency.IdempotencyKey = None) -> MachineOut:
    """Register a machine (a device under /dev, socket:// to an allowed host, or the mock
    firmware).  A port is one machine: a second record on the same physical port is a 409."""
    claim = idempotency.claim(request, idempotency_key, idempotency.canonical(body))
    if (replayed := idempotency.replay(session, claim)) is not None:
        return replayed  # type: ignore[return-value]
    port = PortUrl.parse(body.port)
    is_mock = port.is_mock
    if body.mock is not None and not is_mock:
        raise InvalidInput("mock settings need a mock:// port", field="mock", value=body.port)
    if body.mock is not None and body.mock.true_part_id is not None:
        if session.get(Part, body.mock.true_part_id) is None:
            raise InvalidInput(f"part {body.mock.true_part_id!r} does not exist", field="mock.true_part_id",
                               value=body.mock.true_part_id)
    if is_mock:
        try:
            parse_mock_options(port.query)
        except InvalidConfig as exc:  # 422 naming the option
            raise translate(exc) from exc
    machine_id = new_id("mach")
    key = port_key(body.port, machine_id, runtime.settings.socket_host_list)
    taken = session.exec(select(Machine.id).where(Machine.port_key == key)).first()
    if taken is None:  # records stored under an older spelling of their port
        taken = port_owner(key, session.exec(select(Machine.id, Machine.port)).all())
    if taken is not None:
        raise Conflict(f"port {body.port!r} is already machine {taken!r}: one record per physical port",
                       field="port", value=body.port)
    mock = body.mock.model_dump() if body.mock else (MockSettings().model_dump() if is_mock else None)
    row = Machine(id=machine_id, name=body.name, port=body.port, port_key=key, baudrate=body.baudrate,
                  dialect=body.dialect, profile=body.profile.model_dump(), mock=mock, created_at=utcnow())
    session.add(row)
    out = machine_out(runtime, row)
    location = f"/api/v1/machines/{machine_id}"
    idempotency.remember(session, claim, 201, out, location=location)
    response.headers["Location"] = location
    try:
        return idempotency.commit(session, claim) or out  # type: ignore[return-value]
    except IntegrityError:  # a concurrent registration of the same port won
        session.rollback()
        raise Conflict(f"port {body.port!r} is already registered: one record per physical port",
                       field="port", value=body.port) from None


@router.get("", dependencies=[Viewer])
def list_machines(runtime: RuntimeDep, session: SessionDep) -> Page[MachineOut]:
    rows = session.exec(select(Machine).order_by(col(Machine.created_at))).all()
    return Page(items=[machine_out(runtime, r) for r in rows], total=len(rows))


@router.get("/{machine_id}", dependencies=[Viewer])
def get_machine(machine_id: str, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    return machine_out(runtime, get_or_404(session, Machine, machine_id))


@router.patch("/{machine_id}", dependencies=[Operator],
              responses={409: {"description": "the profile or baud rate of a connected machine, "
                                               "or a program holds it"}})
def update_machine(machine_id: str, body: MachineUpdate, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    """Rename a machine (any time), or change its baud rate or profile (409 unless it is
    disconnected: the live connection was opened with them).  Never while a program holds it."""
    row = get_or_404(session, Machine, machine_id)
    _free(runtime, machine_id)
    live = runtime.machines.get(machine_id)
    state = live.state if live is not None else "disconnected"
    if (body.baudrate is not None or body.profile is not None) and state != "disconnected":
        field = "profile" if body.profile is not None else "baudrate"
        raise Conflict(f"machine {machine_id!r} is {state}: disconnect it before changing its {field}",
                       field=field, value=state)
    if body.name is not None:
        row.name = body.name
    if body.baudrate is not None:
        row.baudrate = body.baudrate
    if body.profile is not None:
        on, off = machine_dispense(row.dialect)
        profile = body.profile.model_dump()
        profile["dispense_on"] = profile["dispense_on"] or on
        profile["dispense_off"] = profile["dispense_off"] or off
        row.profile = profile
        runtime.machines.forget(machine_id)  # the next connect builds the machine with the new profile
    dispense = _dispense_update(body, (row.profile or {}).get("dispense_by_material") or {})
    if dispense is not None:  # read when a print starts: no reconnect needed
        row.profile = {**(row.profile or {}), "dispense": dispense or None,
                       "dispense_by_material": _remembered(row, dispense)}
    session.add(row)
    session.commit()
    session.refresh(row)
    return machine_out(runtime, row)


def _remembered(row: Machine, dispense: dict) -> dict:
    """``profile.dispense_by_material`` with ``dispense`` kept as the machine's own profile of
    its material (a profile of one's own, without a material, is not kept)."""
    tuned = dict((row.profile or {}).get("dispense_by_material") or {})
    name = dispense.get("material")
    if name:
        tuned[name] = dispense
        if len(tuned) > MAX_MATERIAL_PROFILES:
            raise InvalidInput(f"machine {row.id!r} already keeps {MAX_MATERIAL_PROFILES} material profiles",
                               field="dispense.material", value=name)
    return tuned


def _dispense_update(body: MachineUpdate, tuned: dict) -> dict | None:
    """The new ``profile.dispense`` a request asks for ({} to remove it), or None to keep it;
    ``material`` takes the machine's own profile of it (``tuned``) before the preset's."""
    if body.clear_dispense:
        return {}
    if body.dispense is not None:
        return body.dispense.model_dump()
    if body.material is not None:
        if body.material in tuned:
            return dict(tuned[body.material])
        preset = BY_NAME.get(body.material)
        if preset is None or preset.dispense is None:
            known = ", ".join(m.name for m in MATERIALS if m.dispense is not None)
            raise InvalidInput(f"no dispensed material {body.material!r} (known: {known})", field="material",
                               value=body.material)
        return preset.dispense.model_dump()
    return None


@router.get("/{machine_id}/calibration", dependencies=[Viewer], responses={404: {"description": "no such machine"}})
def get_calibration(machine_id: str, session: SessionDep) -> CalibrationOut:
    """The machine's current calibration (probe radius and pre-travel, nozzle offsets) with
    uncertainties, ages, the jobs that measured them and flags (stale, disagreeing re-check)."""
    row = get_or_404(session, Machine, machine_id)
    current = current_calibration(JobReads(session), machine_id)
    return CalibrationOut.model_validate(calibration_summary(machine_id, current, machine_profile(row)))


def _cancel_what_runs(runtime: Runtime, machine_id: str) -> None:
    """An operator's connect/disconnect ends the program on the machine (cancelled, not
    interrupted): ask its job to cancel before the link goes."""
    for job_id in runtime.store.jobs_on_machine(machine_id, ("queued", "running")):
        runtime.store.request_cancel(job_id)


@router.post("/{machine_id}/connect", dependencies=[Operator])
def connect_machine(machine_id: str, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    """Open the port and identify the firmware (503 if unreachable); cancels what runs."""
    row = get_or_404(session, Machine, machine_id)
    _cancel_what_runs(runtime, machine_id)
    runtime.machines.connect(row)
    return machine_out(runtime, row)


@router.post("/{machine_id}/disconnect", dependencies=[Operator])
def disconnect_machine(machine_id: str, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    """Close the port; the program running on it is cancelled."""
    row = get_or_404(session, Machine, machine_id)
    _cancel_what_runs(runtime, machine_id)
    runtime.machines.disconnect(machine_id)
    return machine_out(runtime, row)


def _act(runtime: Runtime, session: Session, machine_id: str, action: str) -> MachineOut:
    row = get_or_404(session, Machine, machine_id)
    machine = runtime.machines.require(machine_id)
    with hardware_errors():
        getattr(machine, action)()
    return machine_out(runtime, row)


@router.post("/{machine_id}/pause", dependencies=[Operator])
def pause_machine(machine_id: str, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    """Stop sending program lines (409 unless printing)."""
    return _act(runtime, session, machine_id, "pause")


@router.post("/{machine_id}/resume", dependencies=[Operator])
def resume_machine(machine_id: str, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    return _act(runtime, session, machine_id, "resume")


def _exists(runtime: Runtime, machine_id: str) -> bool:
    with Session(runtime.engine) as session:
        return session.get(Machine, machine_id) is not None


@router.post("/{machine_id}/stop", dependencies=[Operator], response_model=StopOut,
             responses={404: {"description": "no such machine"}, 409: {"description": "not connected"}})
async def stop_machine(machine_id: str, runtime: RuntimeDep) -> StopOut:
    """Emergency stop (M112 / grbl 0x18), always sent while connected, whatever runs (the
    firmware decides).  An async route: it never waits on the request thread pool, the
    database or a job; the write goes through the stop threads to the link, which becomes
    terminal first (no program byte follows the stop).  The running job ends cancelled."""
    started = time.perf_counter()
    machines = runtime.machines
    machine = machines.get(machine_id)
    if machine is None or machine.link is None:
        exists = await asyncio.get_running_loop().run_in_executor(machines.stop_pool, _exists, runtime, machine_id)
        if not exists:
            raise NotFound(f"machine {machine_id!r} does not exist", field="machine_id", value=machine_id)
        raise Conflict(f"machine {machine_id!r} is not connected: nothing to send the stop to",
                       field="state", value="disconnected")
    try:
        await asyncio.get_running_loop().run_in_executor(machines.stop_pool, machine.emergency_stop)
    except HardwareError as exc:
        raise translate(exc) from exc
    return StopOut(id=machine_id, state=machine.state, stop_sent=True,
                   elapsed_ms=(time.perf_counter() - started) * 1000)


@router.post("/{machine_id}/print", status_code=202, dependencies=[Operator])
def print_on_machine(machine_id: str, body: PrintRequest, runtime: RuntimeDep, session: SessionDep,
                     response: Response) -> JobOut:
    """Start a print job streaming an uploaded program or a job's G-code artifact (409 if busy)."""
    get_or_404(session, Machine, machine_id)
    params = {"machine_id": machine_id, **body.model_dump(exclude_none=True)}
    job = runtime.submit("print", params)
    response.headers["Location"] = f"/api/v1/jobs/{job.id}"
    return load_job_out(session, job.id)


# ---- manual control: an operator's explicit requests, never while a program holds the machine


def _free(runtime: Runtime, machine_id: str) -> None:
    """409 while a program holds the machine, naming the job and how to resume, abandon or
    cancel it."""
    holding = runtime.store.holding_job(machine_id)
    if holding is not None:
        raise Conflict(f"{holding_message(machine_id, holding)}; manual control waits until it ends",
                       field="machine_id", value=machine_id)


@router.post("/{machine_id}/home", dependencies=[Operator])
def home_machine(machine_id: str, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    """Home every axis (the profile's home command, else G28 / $H); 409 while a program holds
    the machine or it is not connected."""
    row = get_or_404(session, Machine, machine_id)
    _free(runtime, machine_id)
    machine = runtime.machines.require(machine_id)
    with hardware_errors():
        machine.home()
    return machine_out(runtime, row)


@router.post("/{machine_id}/unlock", dependencies=[Operator])
def unlock_machine(machine_id: str, body: UnlockRequest, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    """Clear the controller's alarm lock (grbl ``$X``) once the operator confirms the machine
    was checked; 409 while a program holds the machine, when it is not connected or its
    firmware has no alarm lock (Marlin)."""
    row = get_or_404(session, Machine, machine_id)
    _free(runtime, machine_id)
    machine = runtime.machines.require(machine_id)
    if not hasattr(machine, "unlock"):
        raise Conflict(f"machine {machine_id!r} ({row.dialect}) has no alarm lock to clear", field="dialect",
                       value=row.dialect)
    with hardware_errors():
        machine.unlock()
    return machine_out(runtime, row)


@router.post("/{machine_id}/jog", dependencies=[Operator])
def jog_machine(machine_id: str, body: JogRequest, runtime: RuntimeDep, session: SessionDep) -> MachineOut:
    """Move the tool by (dx, dy, dz) mm from where it is, then report where it is."""
    if not (body.dx_mm or body.dy_mm or body.dz_mm):
        raise InvalidInput("a jog needs a non-zero dx_mm, dy_mm or dz_mm", field="dx_mm", value=0.0)
    row = get_or_404(session, Machine, machine_id)
    _free(runtime, machine_id)
    machine = runtime.machines.require(machine_id)
    with hardware_errors():
        x, y, z = machine.position()
        machine.move(x + body.dx_mm, y + body.dy_mm, z + body.dz_mm, feed_mm_min=body.feed_mm_min)
    return machine_out(runtime, row)


@router.post("/{machine_id}/command", dependencies=[Operator])
def console_command(machine_id: str, body: ConsoleRequest, runtime: RuntimeDep, session: SessionDep) -> ConsoleOut:
    """Send one command and return the firmware's reply lines; 422 naming ``command`` when the
    firmware refuses it (unsupported, malformed), 502 when it halts or raises an alarm."""
    row = get_or_404(session, Machine, machine_id)
    _free(runtime, machine_id)
    machine = runtime.machines.require(machine_id)
    with hardware_errors():
        result = machine.send(body.command.strip())
    lines = getattr(result, "reply_lines", None)
    reply = [str(line) for line in lines] if lines is not None else [str(result)]
    return ConsoleOut(command=body.command.strip(), reply=reply, machine=machine_out(runtime, row))


@router.delete("/{machine_id}", status_code=204)
def delete_machine(machine_id: str, runtime: RuntimeDep, session: SessionDep, role: str = Operator,
                   force: Annotated[bool, Query(description="admin only: delete even if jobs reference it")] = False,
                   ) -> None:
    """Remove a machine record (disconnecting it); 409 while a queued or running job uses it
    unless ``force`` (admin), and always while a program holds it.  Finished jobs keep their
    records (their parameters still name the machine's id)."""
    if force and role != "admin":
        raise HTTPException(403, "force=true needs the admin role")
    if not lock_for_delete(session, Machine, [machine_id]):
        session.rollback()
        raise NotFound(f"machine {machine_id!r} does not exist", field="machine_id", value=machine_id)
    _free(runtime, machine_id)
    active = session.exec(select(JobReference.job_id).join(Job, Job.id == JobReference.job_id).where(  # type: ignore[arg-type]
        JobReference.ref_kind == "machine", JobReference.ref_id == machine_id,
        Job.status.not_in(TERMINAL_STATES))).all()  # type: ignore[attr-defined]
    if active and not force:
        session.rollback()
        raise Conflict(f"machine {machine_id!r} has {len(set(active))} unfinished job(s), e.g. "
                       f"{sorted(set(active))[0]}: "
                       "cancel or finish them first", field="machine_id", value=machine_id)
    runtime.machines.forget(machine_id)
    session.exec(delete(JobReference).where(col(JobReference.ref_kind) == "machine",
                                            col(JobReference.ref_id) == machine_id))
    session.delete(get_or_404(session, Machine, machine_id))
    session.commit()
