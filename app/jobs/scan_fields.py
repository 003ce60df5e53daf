"""The checked field of a ``scan_run``, as ``reconstruct`` (``scan_run_job_id``) reads it.

``scan_run`` stores the field it fitted to its samples with its verification touches
(artifact ``field.npz``, :mod:`app.reconstruction.scan_field_store`); this reads it back once
per process (cached by the scan's id: a succeeded job's artifacts never change) and checks
that the traces asked for are the scan's.
"""

from __future__ import annotations

from app.domain.errors import InvalidInput
from app.parts.lru import ByteLru
from app.reconstruction.field import fit_bytes
from app.reconstruction.scan_field import ScanFieldCheck
from app.reconstruction.scan_field_store import scan_check_from_npz
from app.runtime.context import JobContext

FIELD_ARTIFACT = "field.npz"
SCAN_FIELDS = ByteLru(64 * 2 ** 20)


def scan_field(ctx: JobContext, scan_run_job_id: str, traces: list[str],
               trace_field: str = "params.trace_id") -> tuple[ScanFieldCheck, None, list[str]]:
    """(the scan's checked field, None (no probe refinement), the scan's trace ids); every trace
    of ``traces`` must be one of the scan's (422 on ``trace_field`` otherwise)."""
    job = ctx.job(scan_run_job_id, kind="scan_run", field="params.scan_run_job_id")
    trace_ids = list(job.params["trace_ids"])
    known = set(trace_ids)
    for index, trace_id in enumerate(traces):
        if trace_id not in known:
            where = trace_field if trace_field == "params.trace_id" else f"{trace_field}.{index}"
            raise InvalidInput(f"trace {trace_id!r} is not one of the traces scanned by scan run {job.id!r}",
                               field=where, value=trace_id)
    check = SCAN_FIELDS.get(job.id)
    if check is None:
        check = scan_check_from_npz(ctx.artifact_bytes(job.id, FIELD_ARTIFACT))
        SCAN_FIELDS.put(job.id, check, fit_bytes(check.fit))
    return check, None, trace_ids
