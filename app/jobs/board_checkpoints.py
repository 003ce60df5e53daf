"""Per-trace checkpoints of a board job (``reconstruct`` / ``compensate`` with ``trace_ids``):
a retried attempt redoes only the traces the earlier attempt did not finish.

A board job stores each trace's outputs as its own artifacts (``print.<trace_id>.gcode``,
``reconstruction.<trace_id>.npz``...) and records the trace as done; the records are stored
in groups (every CHECKPOINT_TRACES traces or CHECKPOINT_S seconds, and at the end) as the
artifact ``checkpoint.<first trace_id of the group>.json``.  Outputs given to
:meth:`TraceCheckpoints.add` are stored with their group's checkpoint in ONE commit (a
transaction per group, not per trace: each costs a commit and its bookkeeping); outputs a
job stored itself are recorded with :meth:`TraceCheckpoints.done`.  A checkpoint::

    {"traces": [{"trace_id": str, "inputs_sha256": str, "artifacts": {name: sha256}, "row": {...}}, ...]}

``row`` is the trace's row of the job's result; ``inputs_sha256`` the hash of everything the
trace's outputs were made from (:func:`inputs_sha256`: the job's parameters, the trace's
record, the part's and the input artifacts' sha256, the software version...).

Why a trace can be trusted: a blob is written to a temporary file, put on disk (its contents,
and after its rename its directory entry) before its artifact row is committed
(:mod:`app.platform.blobs`), so a SIGKILL leaves either no row or a row over a whole file; a group's
checkpoint is committed with (or after) its traces' artifacts, so a kill before that commit
leaves traces without a record (and, for :meth:`~TraceCheckpoints.add`, files without rows,
which the blob sweep removes), which are done again: at most a group's worth of work is lost.  On reuse the checkpoint's
bytes must hash to its listed sha256, every artifact the trace's record names must still be listed with that sha256 and
its bytes hash to it (an attempt that rewrote an artifact and was killed before recording it, a missing or altered
blob: the trace is done again), and the inputs must be this attempt's.
"""

from __future__ import annotations

import hashlib
import json
import time
from typing import Any

import app
from app.domain.errors import ConformaError
from app.runtime.context import JobContext

CHECKPOINT_MEDIA_TYPE = "application/json"
Output = tuple[str, bytes, str, dict[str, Any] | None]
"""An artifact to store: (name, bytes, media type, meta)."""


CHECKPOINT_TRACES = 25  # a group is stored after this many traces...
CHECKPOINT_S = 1.0  # ...or this long after the previous one, whichever comes first


def checkpoint_name(trace_id: str) -> str:
    """The name of the checkpoint artifact of the group whose first trace is ``trace_id``."""
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
    with ctx.reads() as reads:
        return reads.artifact_shas(job_id)


class TraceCheckpoints:
    """The checkpoints of the running job: which traces an earlier attempt finished (read
    when made), and this attempt's finished traces (stored in groups by :meth:`done`)."""

    def __init__(self, ctx: JobContext) -> None:
        self.ctx = ctx
        self.stored = artifact_shas(ctx, ctx.job_id)  # what earlier attempts left (empty on a first run)
        self.earlier: dict[str, list[dict[str, Any]]] = {}  # trace id -> its records, from intact checkpoints
        for name in sorted(n for n in self.stored if n.startswith("checkpoint.") and n.endswith(".json")):
            data = self._verified(name, self.stored[name])
            try:
                records = json.loads(data)["traces"] if data is not None else []
            except (ValueError, KeyError, TypeError):
                continue
            for record in records if isinstance(records, list) else ():
                if isinstance(record, dict) and isinstance(record.get("trace_id"), str):
                    self.earlier.setdefault(record["trace_id"], []).append(record)
        self.reused = 0
        self.pending: list[dict[str, Any]] = []
        self.outputs: list[Output] = []  # the pending traces' outputs not stored yet
        self.flushed_at = time.monotonic()

    def _verified(self, name: str, sha256: Any) -> bytes | None:
        """The artifact's bytes when it is listed with ``sha256`` and its blob hashes to it."""
        if not isinstance(sha256, str) or self.stored.get(name) != sha256:
            return None
        try:
            data = self.ctx.artifact_bytes(self.ctx.job_id, name)
        except (OSError, ConformaError):
            return None
        return data if hashlib.sha256(data).hexdigest() == sha256 else None

    def reusable(self, trace_id: str, inputs: str) -> dict[str, Any] | None:
        """The trace's result row when an earlier attempt stored all of its outputs from the
        same ``inputs`` (:func:`inputs_sha256`) and recorded it, else None (to be done)."""
        for record in self.earlier.get(trace_id, ()):  # several when attempts made it again
            artifacts, row = record.get("artifacts"), record.get("row")
            if record.get("inputs_sha256") != inputs or not isinstance(artifacts, dict) or not artifacts \
                    or not isinstance(row, dict):
                continue
            if all(self._verified(name, sha) is not None for name, sha in artifacts.items()):
                self.reused += 1
                return row
        return None

    def done(self, trace_id: str, inputs: str, artifacts: dict[str, str], row: dict[str, Any]) -> None:
        """Record a trace whose ``artifacts`` ({name: sha256}) are stored; the group is stored
        when it is full or old enough."""
        self.pending.append({"trace_id": trace_id, "inputs_sha256": inputs, "artifacts": artifacts, "row": row})
        if len(self.pending) >= CHECKPOINT_TRACES or time.monotonic() - self.flushed_at >= CHECKPOINT_S:
            self.flush()

    def add(self, trace_id: str, inputs: str, outputs: list[Output], row: dict[str, Any]) -> None:
        """Record a trace with its ``outputs`` (name, bytes, media type, meta), which are
        stored with the group's checkpoint in one commit (:meth:`flush`)."""
        self.outputs += outputs
        self.done(trace_id, inputs, {name: hashlib.sha256(data).hexdigest() for name, data, _, _ in outputs}, row)

    def flush(self) -> None:
        """Store the recorded traces not stored yet as one checkpoint artifact, in the same
        commit as their outputs not stored yet."""
        if self.pending:
            first = self.pending[0]["trace_id"]
            checkpoint = (checkpoint_name(first), json.dumps({"traces": self.pending}, default=_plain).encode(),
                          CHECKPOINT_MEDIA_TYPE, {"format": "checkpoint", "traces": len(self.pending)})
            self.ctx.artifacts([*self.outputs, checkpoint])
            self.pending, self.outputs = [], []
        self.flushed_at = time.monotonic()

    def note(self) -> str:
        """The progress message's words about reused traces ("" when none were)."""
        return f" ({self.reused} reused from an earlier attempt)" if self.reused else ""


def _plain(value: Any) -> Any:
    """numpy arrays and scalars as JSON (what the stored result holds)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
