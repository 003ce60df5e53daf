"""Per-trace checkpoints of a board job (``reconstruct`` / ``compensate`` with ``trace_ids``):
a retried attempt redoes only the traces the earlier attempt did not finish.

A board job stores each trace's outputs as its own artifacts (``print.<trace_id>.gcode``,
``reconstruction.<trace_id>.npz``...).  When a trace's outputs are all stored, the job
stores one more artifact, the trace's checkpoint ``checkpoint.<trace_id>.json``::

    {"trace_id": str, "inputs_sha256": str, "artifacts": {name: sha256}, "row": {...}}

``row`` is the trace's row of the job's result; ``inputs_sha256`` the hash of everything the
trace's outputs were made from (:func:`inputs_sha256`: the job's parameters, the trace's
record, the part's and the input artifacts' sha256, the software version...).

Why a trace can be trusted: a blob is written to a temporary file, fsynced and renamed
before its artifact row is committed (:mod:`app.blobs`), so a SIGKILL leaves either no row
or a row over a whole file; the checkpoint is committed after the trace's artifacts, so a
kill between them leaves a trace without a checkpoint, which is done again.  On reuse every
named artifact must still be listed with the checkpoint's sha256 and its bytes must hash to
it (an attempt that rewrote an artifact and was killed before its checkpoint, a missing or
altered blob: the trace is done again), and the inputs must be the same as this attempt's.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from sqlmodel import select

import app
from app.errors import ConformaError
from app.jobs.context import JobContext
from app.models import Artifact

CHECKPOINT_MEDIA_TYPE = "application/json"


def checkpoint_name(trace_id: str) -> str:
    """The checkpoint artifact's name of one trace."""
    return f"checkpoint.{trace_id}.json"


def inputs_sha256(*inputs: Any) -> str:
    """sha256 (hex) of ``inputs`` as canonical JSON, with the software version (an upgraded
    worker redoes the traces an older one made)."""
    text = json.dumps([app.__version__, *inputs], sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def trace_inputs(trace: Any, part_sha256: str) -> dict[str, Any]:
    """What of a trace's record (and its part) the trace's outputs depend on."""
    return {"id": trace.id, "part_id": trace.part_id, "part_sha256": part_sha256, "frame": trace.frame,
            "geometry": trace.geometry, "standoff_mm": trace.standoff_mm, "feed_mm_min": trace.feed_mm_min,
            "width_mm": trace.width_mm}


def artifact_shas(ctx: JobContext, job_id: str) -> dict[str, str]:
    """{artifact name: sha256} of ``job_id``'s stored artifacts."""
    with ctx.session() as session:
        rows = session.exec(select(Artifact.name, Artifact.sha256).where(Artifact.job_id == job_id)).all()
    return {name: sha for name, sha in rows}


class TraceCheckpoints:
    """The checkpoints of the running job: which traces an earlier attempt finished."""

    def __init__(self, ctx: JobContext) -> None:
        self.ctx = ctx
        self.stored = artifact_shas(ctx, ctx.job_id)  # what earlier attempts left (empty on a first run)
        self.reused = 0

    def _verified(self, name: str, sha256: str | None) -> bytes | None:
        """The artifact's bytes when it is listed with ``sha256`` and its blob hashes to it."""
        if sha256 is None or self.stored.get(name) != sha256:
            return None
        try:
            data = self.ctx.artifact_bytes(self.ctx.job_id, name)
        except (OSError, ConformaError):
            return None
        return data if hashlib.sha256(data).hexdigest() == sha256 else None

    def reusable(self, trace_id: str, inputs: str) -> dict[str, Any] | None:
        """The trace's result row when an earlier attempt stored all of its outputs from the
        same ``inputs`` (:func:`inputs_sha256`), else None (the trace is to be done)."""
        name = checkpoint_name(trace_id)
        data = self._verified(name, self.stored.get(name))
        if data is None:
            return None
        try:
            record = json.loads(data)
        except ValueError:
            return None
        if not isinstance(record, dict) or record.get("inputs_sha256") != inputs or record.get("trace_id") != trace_id:
            return None
        artifacts = record.get("artifacts")
        if not isinstance(artifacts, dict) or not isinstance(record.get("row"), dict):
            return None
        if any(self._verified(a, sha) is None for a, sha in artifacts.items()):
            return None
        self.reused += 1
        return record["row"]

    def record(self, trace_id: str, inputs: str, artifacts: dict[str, str], row: dict[str, Any]) -> None:
        """Store the trace's checkpoint once its ``artifacts`` ({name: sha256}) are stored."""
        body = {"trace_id": trace_id, "inputs_sha256": inputs, "artifacts": artifacts, "row": row}
        self.ctx.artifact(checkpoint_name(trace_id), json.dumps(body, default=_plain).encode(), CHECKPOINT_MEDIA_TYPE,
                          {"format": "checkpoint", "trace_id": trace_id})

    def note(self) -> str:
        """The progress message's words about reused traces ("" when none were)."""
        return f" ({self.reused} reused from an earlier attempt)" if self.reused else ""


def _plain(value: Any) -> Any:
    """numpy arrays and scalars as JSON (what the stored result holds)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
