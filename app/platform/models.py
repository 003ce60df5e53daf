"""SQLModel tables.  The job table is the source of truth for job state.

Ids are short random strings; timestamps are timezone-aware UTC; JSON columns carry
structured parameters and results.  Schema changes go through an Alembic revision in
``migrations/``.
"""

from __future__ import annotations

import secrets
from datetime import UTC, datetime

from sqlalchemy import JSON, Column, DateTime, Index, UniqueConstraint, text
from sqlmodel import Field, SQLModel

# Constraint names are deterministic so that batch migrations on SQLite can find them.
SQLModel.metadata.naming_convention = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

JOB_STATES = ("queued", "running", "succeeded", "needs_attention", "failed", "cancelled", "interrupted", "waiting")
# ``waiting``: a workflow (a closed loop) stopped at one of its pause points and holds no
# worker: it waits for an operator's continue, accept, add-stations or abandon (what it
# waits at is its ``program_state["waiting"]``); nothing moves meanwhile.
TERMINAL_STATES = ("succeeded", "needs_attention", "failed", "cancelled")
# A job that ran to its end: its result is complete.  ``needs_attention``: it did, but the
# result asks the operator to act before it is relied on (a closed loop whose field check
# failed: it printed nothing; add stations and refit, or accept explicitly).
COMPLETED_STATES = ("succeeded", "needs_attention")
ATTENTION_KEY = "needs_attention"  # a kind's result with this key true ends the job in that state
# A machine job in these states holds its machine: at most one per machine (a unique
# partial index, so that concurrent submissions cannot both win).  ``interrupted`` waits
# for an operator to resume or abandon it.
MACHINE_HOLDING_STATES = ("queued", "running", "interrupted")
_HOLDING_SQL = "machine_id IS NOT NULL AND status IN ('queued', 'running', 'interrupted')"

def new_id(prefix: str) -> str:
    """A random, URL-safe id such as ``job_4f3a9c1e0b7d2a65``."""
    return f"{prefix}_{secrets.token_hex(8)}"

def utcnow() -> datetime:
    return datetime.now(UTC)

class Blob(SQLModel, table=True):
    """A content-addressed file under ``data_dir/blobs`` (sha256 of its bytes)."""

    __tablename__ = "blobs"
    sha256: str = Field(primary_key=True, max_length=64)
    bytes: int
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))

class Part(SQLModel, table=True):
    __tablename__ = "parts"
    id: str = Field(primary_key=True, max_length=40)
    name: str = Field(max_length=200)
    format: str = Field(max_length=10)
    faces: int
    vertices: int
    bounds: list = Field(sa_column=Column(JSON, nullable=False))
    watertight: bool
    volume_mm3: float | None = None
    area_mm2: float
    sha256: str = Field(foreign_key="blobs.sha256", max_length=64, index=True)
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))
    # intake frame (migration 0006): the stored mesh (sha256, format) is in mm with +Z up;
    # the uploaded file is source_sha256 / source_format when it had to be converted
    units: str = Field(default="mm", max_length=8)
    frame: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    source_sha256: str | None = Field(default=None, foreign_key="blobs.sha256", max_length=64)
    source_format: str | None = Field(default=None, max_length=10)
    warnings: list | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    defects: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))

class Trace(SQLModel, table=True):
    __tablename__ = "traces"
    id: str = Field(primary_key=True, max_length=40)
    part_id: str = Field(foreign_key="parts.id", index=True, max_length=40)
    name: str = Field(max_length=200)
    frame: str = Field(max_length=4)
    geometry: dict = Field(sa_column=Column(JSON, nullable=False))
    standoff_mm: float
    width_mm: float | None = None
    feed_mm_min: float | None = None
    length_mm: float
    z_min: float
    z_max: float
    nominal: dict = Field(sa_column=Column(JSON, nullable=False))
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))
    #: where an imported trace came from: {file, layer, net, width_mm, entity, import_id, mapping, stretch}
    source: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))

class Job(SQLModel, table=True):
    __tablename__ = "jobs"
    __table_args__ = (Index("ix_jobs_status_lease", "status", "lease_until"),
                      Index("uq_jobs_active_machine", "machine_id", unique=True,
                            sqlite_where=text(_HOLDING_SQL), postgresql_where=text(_HOLDING_SQL)))
    id: str = Field(primary_key=True, max_length=40)
    kind: str = Field(max_length=40, index=True)
    status: str = Field(default="queued", max_length=20, index=True)
    progress: float = 0.0
    message: str = Field(default="", max_length=500)
    params: dict = Field(sa_column=Column(JSON, nullable=False))
    result: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    # the result's size as stored (bytes of its JSON) and its summary (app.jobs.results.models.result_summary):
    # what the job's record shows in place of a large result
    result_bytes: int | None = None
    result_summary: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    error: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    parent_id: str | None = Field(default=None, foreign_key="jobs.id", index=True, max_length=40)
    queue: str = Field(default="default", max_length=40)
    attempts: int = 0
    max_attempts: int = 3
    worker: str | None = Field(default=None, max_length=120)
    lease_until: float | None = None
    cancel_requested: bool = False
    input_hashes: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    software_version: str = Field(default="", max_length=40)
    revision: int = 0
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))
    enqueued_at: float | None = None
    started_at: datetime | None = Field(default=None, sa_column=Column(DateTime(timezone=True)))
    finished_at: datetime | None = Field(default=None, sa_column=Column(DateTime(timezone=True)))
    # machine jobs (print, probe_run, register): the machine they drive, and where the
    # program stands (last executed / acknowledged command, interruption, resume)
    machine_id: str | None = Field(default=None, max_length=40)
    program_state: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    # compute jobs: the process that runs (ran) its latest attempt, {"pid", "start_ticks",
    # "boot_id"} (app.runtime.process_identity): a later attempt runs only once it has ended
    process: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    # the attempts that ended without finishing and were queued again (a lost lease: the
    # worker stopped reporting), oldest first: [{"attempt", "ended_at" (ISO 8601 UTC), "reason"}]
    earlier_attempts: list | None = Field(default=None, sa_column=Column(JSON, nullable=True))

class JobReference(SQLModel, table=True):
    """Which stored records a job reads (parts, traces, other jobs): guards deletion."""

    __tablename__ = "job_references"
    job_id: str = Field(foreign_key="jobs.id", primary_key=True, max_length=40)
    ref_kind: str = Field(primary_key=True, max_length=12)
    ref_id: str = Field(primary_key=True, max_length=40, index=True)

class Artifact(SQLModel, table=True):
    __tablename__ = "artifacts"
    __table_args__ = (UniqueConstraint("job_id", "name"),)
    id: int | None = Field(default=None, primary_key=True)
    job_id: str = Field(foreign_key="jobs.id", index=True, max_length=40)
    name: str = Field(max_length=200)
    media_type: str = Field(max_length=100)
    bytes: int
    sha256: str = Field(foreign_key="blobs.sha256", max_length=64)
    meta: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))

class Machine(SQLModel, table=True):
    __tablename__ = "machines"
    id: str = Field(primary_key=True, max_length=40)
    name: str = Field(max_length=200)
    port: str = Field(max_length=500)
    # the physical port, normalised (real path of a device, lower-case socket host):
    # unique, so two records can never drive one controller
    port_key: str | None = Field(default=None, max_length=500, unique=True)
    baudrate: int = 115200
    dialect: str = Field(max_length=10)
    profile: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    mock: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))

class ApiKey(SQLModel, table=True):
    """A stored API key: only its sha256 is kept; ``prefix`` helps people tell keys apart."""

    __tablename__ = "api_keys"
    id: str = Field(primary_key=True, max_length=40)
    name: str = Field(default="", max_length=200)
    role: str = Field(max_length=10)
    prefix: str = Field(max_length=12)
    key_sha256: str = Field(max_length=64, unique=True)
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))
    revoked_at: datetime | None = Field(default=None, sa_column=Column(DateTime(timezone=True)))


class Program(SQLModel, table=True):
    """An uploaded G-code program (the file is a blob)."""

    __tablename__ = "programs"
    id: str = Field(primary_key=True, max_length=40)
    name: str = Field(max_length=200)
    sha256: str = Field(foreign_key="blobs.sha256", max_length=64)
    lines: int
    commands: int
    commands_sha256: str = Field(max_length=64)
    bounds: list | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))


class UploadedFile(SQLModel, table=True):
    """A user's data file (a measured height map, a mask image...) that jobs can read."""

    __tablename__ = "files"
    id: str = Field(primary_key=True, max_length=40)
    name: str = Field(max_length=200)
    media_type: str = Field(max_length=100)
    bytes: int
    sha256: str = Field(foreign_key="blobs.sha256", max_length=64)
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))


class CircuitImport(SQLModel, table=True):
    """One committed circuit import: its files, placement options, the traces it created and
    the mapped pads and areas (top-view outlines, mm) that a circuit program fills."""

    __tablename__ = "circuit_imports"
    id: str = Field(primary_key=True, max_length=40)
    part_id: str = Field(index=True, max_length=40)  # no foreign key: a part may be deleted
    files: list = Field(sa_column=Column(JSON, nullable=False))
    options: dict = Field(sa_column=Column(JSON, nullable=False))
    trace_ids: list = Field(sa_column=Column(JSON, nullable=False))
    pads: list = Field(sa_column=Column(JSON, nullable=False))
    areas: list = Field(sa_column=Column(JSON, nullable=False))
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False))

class IdempotencyRecord(SQLModel, table=True):
    """The answer to a creating POST sent with an ``Idempotency-Key`` (per API key), written in
    the transaction that creates the record, so that a retry gets the same record back."""

    __tablename__ = "idempotency_keys"
    owner: str = Field(primary_key=True, max_length=64)  # sha256 of the API key
    key: str = Field(primary_key=True, max_length=255)
    scope: str = Field(max_length=300)  # "POST /api/v1/parts"
    request_sha256: str = Field(max_length=64)
    status_code: int
    body: dict = Field(sa_column=Column(JSON, nullable=False))
    location: str | None = Field(default=None, max_length=300)
    created_at: datetime = Field(sa_column=Column(DateTime(timezone=True), nullable=False, index=True))
