"""What the machine job kinds share: one program per machine, and a connected machine."""

from __future__ import annotations

from sqlmodel import Session, select

from app.errors import Conflict
from app.jobs.context import JobContext
from app.models import Job, JobReference
from hardware.machine import Machine

MACHINE_KINDS = ("print", "probe_run", "register")  # jobs that drive a machine themselves
WORKFLOW_KINDS = ("closed_loop",)  # parents that hold a machine between their children's steps


def refuse_if_machine_busy(machine_id: str, session: Session) -> None:
    """409 when another machine job, or a workflow holding the machine, is queued or running
    on ``machine_id``.  A workflow's own children (``session.info["parent_id"]``, set at
    submission) may use the machine it holds."""
    parent_id = session.info.get("parent_id")
    query = (select(Job.id, Job.kind).join(JobReference, JobReference.job_id == Job.id)
             .where(JobReference.ref_kind == "machine", JobReference.ref_id == machine_id,
                    Job.status.in_(("queued", "running")), Job.kind.in_(MACHINE_KINDS + WORKFLOW_KINDS)))
    if parent_id is not None:
        query = query.where(Job.id != parent_id)
    busy = session.exec(query).first()
    if busy is not None:
        raise Conflict(f"machine {machine_id!r} is busy with {busy[1]} job {busy[0]}; one program at a time",
                       field="params.machine_id", value=machine_id)


def connected_machine(ctx: JobContext, machine_id: str) -> Machine:
    """The live machine, connected now if it was not (or reconnected if its link dropped)."""
    machines = ctx.runtime.machines
    machine = machines.get(machine_id)
    if machine is None or machine.state == "disconnected" or machine.link_lost:
        machine = machines.connect(ctx.machine(machine_id))
    return machine
