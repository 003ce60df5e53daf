"""What the machine job kinds share: one program per machine (held by the database), one
execution thread per machine, a connected machine, and the operator-only recovery.

Recovery rule: nothing moves a machine without an operator's request.  When a
machine job's link drops, or its process dies, the job becomes ``interrupted`` with
where its program stands (``program_state``); it is never requeued automatically.  The
operator resumes it (``POST /jobs/{id}/resume``: reconnect, ask the machine which command
is known executed, re-home, continue from there) or abandons it.  An operator's
disconnect/connect of the machine, or an emergency stop, cancels what runs on it.
"""

from __future__ import annotations

import logging
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlmodel import Session, select

from app.domain.errors import Cancelled, Conflict, ConformaError
from app.gcode.estimator import command_times
from app.machines.live import MachineFault, MachineUnavailable, hardware_errors
from app.platform.models import Job, utcnow
from app.runtime.context import JobContext
from app.runtime.registry import machine_kinds
from hardware.backend import Machine
from hardware.errors import HardwareError
from hardware.machine import Machine as SerialMachine
from hardware.protocol import validate_program

if TYPE_CHECKING:
    from app.runtime.engine import Runtime
    from app.runtime.reads import JobReads
    from app.runtime.store import JobStore

log = logging.getLogger("conforma.machines")
WORKFLOW_KINDS = ("closed_loop",)  # parents that hold a machine between their children's steps


class Interrupted(ConformaError):
    """The job stopped mid-program and waits for an operator (recorded, not an error)."""

    status = 409
    title = "Interrupted"


def machine_slot(kind: str, params: dict[str, Any]) -> str | None:
    """The machine a job of ``kind`` holds while queued, running or interrupted (the
    ``jobs.machine_id`` column under a unique partial index), or None."""
    if kind in machine_kinds():
        return params.get("machine_id")
    return None


def holding_message(machine_id: str, job: dict[str, Any]) -> str:
    """Why ``machine_id`` is not free, naming the job that holds it (``job``: ``id``,
    ``kind``, ``status`` and, for an interrupted one, ``program_state``) and what an
    operator does about it: an interrupted program waits to be resumed or abandoned,
    a queued or running one to end or be cancelled."""
    job_id, kind, status = job["id"], job["kind"], job["status"]
    if status == "interrupted":
        state = job.get("program_state") or {}
        where = (f" (stopped at command {state['executed']} of {state['total']})"
                 if state.get("executed") is not None and state.get("total") is not None else "")
        return (f"machine {machine_id!r} is held by the interrupted {kind} job {job_id}{where}: resume it "
                f"(GET /api/v1/jobs/{job_id}/resume shows where, POST it with {{\"confirm\": true}}) or "
                f"abandon it (POST /api/v1/jobs/{job_id}/abandon)")
    if status == "waiting":
        at = ((job.get("program_state") or {}).get("waiting") or {}).get("at", "a pause point")
        return (f"machine {machine_id!r} is held by the {kind} job {job_id}, waiting for an operator at {at!r}: "
                f"continue it (POST /api/v1/jobs/{job_id}/continue) or abandon it (POST /api/v1/jobs/{job_id}/abandon)")
    return (f"machine {machine_id!r} is busy with {kind} job {job_id} ({status}); one program at a time: "
            f"wait for it or cancel it (POST /api/v1/jobs/{job_id}/cancel)")


def refuse_if_machine_busy(machine_id: str, reads: JobReads) -> None:
    """409 when another machine job, or a workflow holding the machine, is queued, running,
    interrupted or waiting (at a pause point) on ``machine_id``.  A friendly early answer only: the unique index on
    ``jobs.machine_id`` is what makes two concurrent submissions impossible.  A workflow's
    own children (``reads.parent_id``) may use the machine it holds."""
    busy = reads.machine_holder(machine_id, machine_kinds() + WORKFLOW_KINDS)
    if busy is not None:
        raise Conflict(holding_message(machine_id, busy), field="params.machine_id", value=machine_id)


def connected_machine(ctx: JobContext, machine_id: str) -> Machine:
    """The live machine, connected now if it was not (or reconnected if its link dropped
    and an operator asked to resume)."""
    machines = ctx.runtime.machines
    machine = machines.get(machine_id)
    if machine is None or machine.state == "disconnected" or machine.link_lost:  # never after an e-stop
        machine = machines.connect(ctx.machine(machine_id))
    return machine


def resume_request(ctx: JobContext) -> dict[str, Any] | None:
    """The program state of this job when an operator asked to resume it after it had
    started, else None (a job interrupted before it started simply starts)."""
    with ctx.reads() as reads:
        job = reads.find_job(ctx.job_id)
    state = job.program_state if job is not None else None
    return state if state and state.get("resume_requested") and "total" in state else None


def plan_eta(machine: Machine, lines: list[str]) -> None:
    """Give the machine's program clock each command's estimated duration
    (:func:`app.gcode.estimator.command_times`), so that the machines page's time left is the
    estimate scaled by how fast the machine really goes; a program the estimator cannot read
    keeps the line-rate estimate."""
    try:
        times = command_times(validate_program(lines))
    except (ConformaError, HardwareError) as exc:
        log.info("no time plan for the program: %s", exc)
        return
    machine.clock.expect(np.concatenate([[0.0], np.cumsum(times)]))  # type: ignore[arg-type]


def stopped_by_operator(ctx: JobContext, machine: Machine | None) -> bool:
    """True when the machine was disconnected, reconnected or emergency-stopped by an
    operator (the job was asked to cancel first), as opposed to a link that dropped."""
    return ctx.runtime.store.cancel_requested(ctx.job_id) or (machine is not None and machine.estopped)


def interrupt(ctx: JobContext, machine: Machine | None, exc: BaseException, state: dict[str, Any]) -> ConformaError:
    """Record the job as interrupted (or Cancelled when an operator stopped it) and return
    the exception the kind raises to end its attempt."""
    if stopped_by_operator(ctx, machine):
        reason = "emergency stop" if machine is not None and machine.estopped else \
            "the operator disconnected or reconnected the machine"
        return Cancelled(f"{reason}; the program stopped at command {state.get('executed')}",
                         field="job_id", value=ctx.job_id)
    world = ctx.runtime.machines.world_by_id(machine_id_of(ctx))
    state = {**state, "resume_requested": False, "interrupted_at": utcnow().isoformat(),
             "reason": f"{type(exc).__name__}: {exc}"[:300],
             "position": list(world.position) if world is not None else None}
    message = (f"interrupted at command {state.get('executed')} of {state.get('total')} "
               f"({type(exc).__name__}); an operator must resume or abandon it")
    ctx.runtime.store.interrupt(ctx.claim, state, message)
    return Interrupted(message, field="job_id", value=ctx.job_id)


def machine_for_job(ctx: JobContext, machine_id: str, resume: dict[str, Any] | None) -> Machine:
    """The connected machine of a job.  On an operator's resume in a process that does not
    know the interrupted program (the server restarted), the machine first adopts what
    the job recorded, so that connecting keeps the firmware's line numbering."""
    machines = ctx.runtime.machines
    if resume is not None:
        machine = machines.get(machine_id) or machines.build(ctx.machine(machine_id))
        if machine.interrupted_program is None and machine.link is None:
            machine.adopt_interrupted(int(resume["total"]), int(resume["executed"]), resume.get("acked_line_no"))
    return connected_machine(ctx, machine_id)


def rehomed_machine(ctx: JobContext, machine_id: str, resume: dict[str, Any] | None,
                    state: dict[str, Any]) -> Machine:
    """The connected machine of a touching job (``probe_run``, ``register``): an operator's
    resume re-homes it first (touches are idempotent) and counts the resume in ``state``;
    a failure to reach it interrupts the job (raised)."""
    machine = None
    try:
        machine = connected_machine(ctx, machine_id)
        if resume is not None:
            with hardware_errors():
                machine.home()
            state["resumes"] += 1
    except (HardwareError, MachineUnavailable, MachineFault) as exc:
        raise interrupt(ctx, machine, exc, state) from exc
    return machine


def resume_point(machine: Machine, resume: dict[str, Any]) -> tuple[int, list[str]]:
    """Where a resumed program continues and what was sent before it: the first command
    not known to be executed, then the machine is re-homed.

    Before re-homing, the machine is asked where its tool stands (``locate_resume``): after a
    link drop with the position kept, the program continues at the first command not
    completed (no move runs twice); otherwise by line numbers (Marlin that kept running) or
    the position the controller reported last while streaming (a reset: what may run twice
    is bounded by the motion of one report interval plus the move in progress), or the
    planner bound (a reset without reports: up to a planner's worth of short moves may run
    twice).  The evidence is ``machine.last_resume`` (logged; the print job records it as
    ``resume_location``).  A machine that no longer knows the program
    (another process) continues from the recorded count."""
    if isinstance(machine, SerialMachine):
        machine.last_resume = None  # what this resume found (the job records it), nothing older
    if machine.interrupted_program is None:
        start = int(resume["executed"])
    elif isinstance(machine, SerialMachine):
        located = machine.locate_resume()
        start = located.start
        log.info("resuming at command %d (%s: %s)", located.start, located.basis, located.detail)
    else:
        start = machine.resume_line()
    home = machine.home_command  # the profile's, else the dialect's (hardware.dialects)
    machine.home()
    return start, [home]


def resume_preview(runtime: Runtime, job: Job, row: Any) -> dict[str, Any]:
    """What an operator's resume of the interrupted ``job`` will do, before it moves anything:
    the command it resumes at (``start``, 0-based; ``line`` 1-based), the ``basis``, the
    commands and moves that may run again and ``skipped: 0``, with a ``summary`` sentence.
    For a print whose machine still knows the interrupted program, the machine is reconnected
    if its link was lost (no motion: grbl resets on connect, Marlin keeps running) and asked
    where it stands (``Machine.locate_resume``: the resume itself then continues there);
    otherwise the recorded count, which the resume confirms with the machine."""
    state = job.program_state or {}
    total = state.get("total")
    machine = runtime.machines.get(row.id)
    gap = machine.interrupted_program if machine is not None else None
    if job.kind == "print" and gap is not None and isinstance(machine, SerialMachine):
        with hardware_errors():
            if machine.state == "disconnected" or machine.link_lost:
                runtime.machines.connect(row)
            located = machine.locate_resume()
        out = located.as_dict()
        total = gap.total
    else:
        start = int(state.get("executed", 0))
        out = {"start": start, "basis": "recorded count", "repeats": 0, "repeat_moves": 0, "skipped": 0,
               "detail": "no resume located on this machine (a LinuxCNC machine, or a process that does not hold "
                         "the interrupted program): the resume asks the machine again",
               "summary": f"resumes at command {start + 1} as recorded (the machine is asked again when it "
                          "resumes; it never starts later than what is known to have run)"}
    return {"job_id": job.id, "machine_id": row.id, "total": total, "line": int(out["start"]) + 1, **out}


def request_resume(store: JobStore, job: Job) -> bool:
    """interrupted -> queued with the operator's request recorded in ``program_state``.

    A workflow (``closed_loop``) whose current child is itself interrupted is refused (409
    naming the child): the child holds the machine and the probes it already made, so the
    operator resumes the child first (its program continues where it stopped; the loop, if
    still waiting, continues with it), or abandons it, and then resumes the loop, which
    reuses every child that succeeded and never probes a finished trace again."""
    if job.kind in WORKFLOW_KINDS:
        with Session(store.engine) as session:
            child = session.exec(select(Job.id, Job.kind).where(Job.parent_id == job.id,
                                                                 Job.status == "interrupted")).first()
        if child is not None:
            raise Conflict(f"{job.kind} {job.id} waits for its interrupted {child[1]} job {child[0]}: resume that "
                           "job first (its program continues where it stopped) or abandon it, then resume this one",
                           field="job_id", value=child[0])
    state = {**(job.program_state or {}), "resume_requested": True, "resume_requested_at": utcnow().isoformat()}
    return store.resume(job.id, state, job.revision)


def machine_id_of(ctx: JobContext) -> str:
    return str(ctx.claim.params.get("machine_id"))


class MachineThreads:
    """One execution thread per machine: a job on machine B never waits for machine A.

    The ``machine`` queue's consumer only hands each job id to the thread of the job's
    machine (``jobs.machine_id``) and returns at once; the job is claimed and run there."""

    def __init__(self, runtime: Runtime) -> None:
        self.runtime = runtime
        self._threads: dict[str, ThreadPoolExecutor] = {}
        self._lock = threading.Lock()

    def dispatch(self, job_id: str) -> None:
        machine_id = self.runtime.store.machine_of(job_id) or "unbound"
        with self._lock:
            executor = self._threads.get(machine_id)
            if executor is None:
                executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"machine-{machine_id}")
                self._threads[machine_id] = executor
        executor.submit(self._run, job_id)

    def _run(self, job_id: str) -> None:
        try:
            self.runtime.execute(job_id)
        except Exception:  # execute records failures itself; never kill the thread
            log.exception("machine job %s crashed its thread", job_id)

    def shutdown(self) -> None:
        with self._lock:
            executors, self._threads = list(self._threads.values()), {}
        for executor in executors:
            executor.shutdown(wait=False, cancel_futures=True)
