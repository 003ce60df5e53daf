"""What a running job sees: its parameters, progress reporting, cancel, inputs, artifacts.

Job kinds are thin adapters; everything they need from the service goes through this
object, so a kind never opens the database or the blob directory itself.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

from sqlmodel import Session

from app.errors import Cancelled, ConformaError
from app.jobs.inputs import succeeded_job
from app.jobs.store import Claim
from app.models import TERMINAL_STATES, Artifact, Job, Machine, Part, Trace, UploadedFile
from app.records import add_artifact, get_or_404

if TYPE_CHECKING:
    import trimesh
    from app.jobs.runtime import Runtime


class JobContext:
    """The service side of one running attempt of one job."""

    def __init__(self, runtime: "Runtime", claim: Claim) -> None:
        self.runtime = runtime
        self.claim = claim
        self.job_id = claim.job_id
        self.cancel_event = threading.Event()
        self.lost_event = threading.Event()

    # progress and cancel ---------------------------------------------------------
    def progress(self, fraction: float, message: str | None = None) -> None:
        """Report progress (0..1); renews the lease.  Raises Cancelled when asked to stop."""
        answer = self.runtime.store.heartbeat(self.claim, fraction, message)
        if answer is None:
            self.lost_event.set()
        elif answer:
            self.cancel_event.set()
        self.check_cancelled()

    def check_cancelled(self) -> None:
        if self.cancel_event.is_set():
            raise Cancelled("the job was cancelled", field="job_id", value=self.job_id)
        if self.lost_event.is_set():
            raise Cancelled("this attempt lost its lease to another worker", field="job_id", value=self.job_id)

    # inputs ----------------------------------------------------------------------
    def session(self) -> Session:
        return Session(self.runtime.engine, expire_on_commit=False)

    def part(self, part_id: str) -> Part:
        with self.session() as session:
            return get_or_404(session, Part, part_id)

    def mesh(self, part_id: str) -> trimesh.Trimesh:
        return self.runtime.meshes.mesh(self.part(part_id))

    def trace(self, trace_id: str) -> Trace:
        with self.session() as session:
            return get_or_404(session, Trace, trace_id)

    def machine(self, machine_id: str) -> Machine:
        with self.session() as session:
            return get_or_404(session, Machine, machine_id)

    def job(self, job_id: str, *, kind: str | None = None, field: str = "job_id") -> Job:
        """Another job's record; with ``kind``, it must be of that kind and have succeeded."""
        with self.session() as session:
            if kind is None:
                return get_or_404(session, Job, job_id, field=field)
            return succeeded_job(session, job_id, kind, field, error=ConformaError)

    def artifact_bytes(self, job_id: str, name: str) -> bytes:
        with self.session() as session:
            row = session.query(Artifact).filter(Artifact.job_id == job_id, Artifact.name == name).one_or_none()
        if row is None:
            raise ConformaError(f"job {job_id!r} has no artifact {name!r}", field="artifact", value=name)
        return self.runtime.blobs.read(row.sha256)

    def file_bytes(self, file_id: str, field: str = "file_id") -> bytes:
        """The content of an uploaded file (``POST /api/v1/files``)."""
        with self.session() as session:
            row = get_or_404(session, UploadedFile, file_id, field=field)
        return self.runtime.blobs.read(row.sha256)

    # outputs ---------------------------------------------------------------------
    def artifact(self, name: str, data: bytes, media_type: str, meta: dict[str, Any] | None = None) -> str:
        """Store an artifact of this job; returns its sha256."""
        with self.session() as session:
            artifact = add_artifact(session, self.runtime.blobs, self.job_id, name, data, media_type, meta)
            session.commit()
            return artifact.sha256

    # children --------------------------------------------------------------------
    def submit_child(self, kind: str, params: dict[str, Any]) -> str:
        return self.runtime.submit(kind, params, parent_id=self.job_id).id

    def wait_for(self, job_ids: list[str], *, poll_s: float = 0.05) -> list[Job]:
        """Block until every job in ``job_ids`` is finished.  An operator's cancel of this job
        cancels them too; a lost lease does not (another attempt of this job takes over and
        reuses them: an interrupted child keeps its measured points for the operator's resume)."""
        while True:
            with self.session() as session:
                jobs = [session.get(Job, job_id) for job_id in job_ids]
            if all(job is not None and job.status in TERMINAL_STATES for job in jobs):
                return [job for job in jobs if job is not None]
            try:
                self.check_cancelled()
            except Cancelled:
                if not self.lost_event.is_set():
                    for job_id in job_ids:
                        self.runtime.store.request_cancel(job_id)
                raise
            time.sleep(poll_s)
