"""A closed loop's own files: what an operator downloads from the loop itself
instead of digging through each trace's compensate job.

- ``loop_summary.json`` / ``loop_summary.csv``: one row per trace with its figures (probes,
  model deviation, the compensated program's lines and hash, and with ``evaluate`` the
  standoff and XY errors of the nominal vs the compensated print, µm);
- ``whole_part.gcode``: every trace's compensated program joined in a short-travel order
  with safe lifts between traces, in the machine's dialect (:func:`app.gcode.concat.join_programs`).

Thin: the joining is in :mod:`app.gcode.concat`; this module only reads the children's
artifacts and writes the parent's.
"""

from __future__ import annotations

import csv
import io
import json
from typing import Any

from app.gcode.concat import join_programs
from app.gcode.estimator import estimate_gcode
from app.jobs.gcode_meta import gcode_meta
from app.jobs.results.loop import ClosedLoopResult, LoopTrace, PrintReport
from app.runtime.context import JobContext

SUMMARY_COLUMNS = ("index", "trace_id", "name", "probes", "deviation_max_um", "compensate_job", "program_lines",
                   "program_sha256", "standoff_max_before_um", "standoff_max_after_um", "standoff_rms_before_um",
                   "standoff_rms_after_um", "xy_max_before_um", "xy_max_after_um")
CLEARANCE_MM = 2.0


def _um(value: Any) -> float | None:
    return None if value is None else round(float(value) * 1000.0, 3)


def _measured(report: PrintReport | None, name: str) -> float | None:
    """One figure (µm) of a printed program's measurement, None when it was not measured."""
    return None if report is None else _um(getattr(report, name))


def summary_rows(ctx: JobContext, traces: list[LoopTrace], programs: dict[str, str],
                 metas: dict[str, dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """One row per trace of a closed loop's result (lengths µm); ``programs``: trace id ->
    its compensated program's text; ``metas``: trace id -> that program's stored
    :func:`gcode_meta` (computed from the text where missing)."""
    rows = []
    names = ctx.trace_names([entry.trace_id for entry in traces])
    for index, entry in enumerate(traces, start=1):
        stored = (metas or {}).get(entry.trace_id) or {}
        meta = stored if {"lines", "commands_sha256"} <= stored.keys() else gcode_meta(programs[entry.trace_id])
        evaluation = entry.evaluation
        before = evaluation.nominal if evaluation is not None else None
        after = evaluation.compensated if evaluation is not None else None
        rows.append({
            "index": index, "trace_id": entry.trace_id, "name": names[entry.trace_id],
            "probes": entry.probes, "deviation_max_um": _um(entry.deviation_max_mm),
            "compensate_job": entry.compensate, "program_lines": meta["lines"],
            "program_sha256": meta["commands_sha256"],
            "standoff_max_before_um": _measured(before, "standoff_error_max_mm"),
            "standoff_max_after_um": _measured(after, "standoff_error_max_mm"),
            "standoff_rms_before_um": _measured(before, "standoff_error_rms_mm"),
            "standoff_rms_after_um": _measured(after, "standoff_error_rms_mm"),
            "xy_max_before_um": _measured(before, "xy_error_max_mm"),
            "xy_max_after_um": _measured(after, "xy_error_max_mm"),
        })
    return rows


def _csv(rows: list[dict[str, Any]]) -> bytes:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row[k] is None else row[k] for k in SUMMARY_COLUMNS})
    return out.getvalue().encode()


def write_loop_files(ctx: JobContext, machine_id: str, result: dict[str, Any]) -> dict[str, Any]:
    """Write the loop's summary and whole-part program as the running job's artifacts;
    returns what the result records about them (names, program lines, order, time).
    ``result``: the loop's result so far (read through :class:`ClosedLoopResult`)."""
    dialect = ctx.machine(machine_id).dialect
    traces = ClosedLoopResult.model_validate(result).traces
    # a board compensate job holds every trace's program as print.<trace_id>.gcode (the entry names it)
    stored = ctx.artifacts_of([(e.compensate, e.program) for e in traces])
    programs = {e.trace_id: ctx.blob(stored[(e.compensate, e.program)].sha256).decode() for e in traces}
    rows = summary_rows(ctx, traces, programs, {e.trace_id: stored[(e.compensate, e.program)].meta for e in traces})
    ctx.artifact("loop_summary.json", json.dumps({"traces": rows}, indent=1).encode(), "application/json")
    ctx.artifact("loop_summary.csv", _csv(rows), "text/csv")
    files: dict[str, Any] = {"summary": ["loop_summary.json", "loop_summary.csv"]}
    if rows:
        joined = join_programs([(f"{r['name']} {r['trace_id']}", programs[r["trace_id"]]) for r in rows],
                               dialect, clearance_mm=CLEARANCE_MM, job_id=ctx.job_id)
        meta = gcode_meta(joined.text)
        time_s = estimate_gcode(joined.text).total_s
        ctx.artifact("whole_part.gcode", joined.text.encode(), "text/x-gcode", {**meta, "time_s": time_s})
        files["whole_part"] = {"artifact": "whole_part.gcode", "lines": meta["lines"], "time_s": time_s,
                               "order": [rows[i]["trace_id"] for i in joined.order],
                               "safe_z_mm": joined.safe_z_mm, "travel_xy_mm": joined.travel_xy_mm,
                               "dialect": dialect}
    return files
