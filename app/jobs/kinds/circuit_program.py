"""Job ``circuit_program``: all traces, pads and areas of a circuit import in one program.

Traces come compensated from a ``closed_loop`` over the import's traces (each trace's
``compensate`` child; the per-trace programs stay available there); pads and areas are
filled (contour + raster at ``line_width_mm``) on the nominal surface lifted by the
deviation that loop's probes measured.  The import stores a probe ring inside every pad and
area (traces with ``source.role`` ``pad_probe``); the loop must include them (when pads are
filled), so every fill is compensated from stations on its own pad, not extrapolated.
Areas keep their holes (the rings around other nets' pads and tracks), and no fill covers
them.  Before anything is written, the copper to print (traces at their width, pads, area
fills) is checked against the netlist (:mod:`app.circuits.nets`): a program that would join
two nets is refused at submission (422) naming both nets, the items and where they meet,
and so is one that would open a net: the printed items (traces at the width they print,
fills as their beads cover them, pads off the part left out) of a piece of a net the source
file connects no longer connected (:mod:`app.circuits.opens`), naming the net and the gap.
After a loop in machine coordinates (a placement or registration) every printed point goes
through the loop's part -> machine placement: the traces' compensated tips already are, pad
and area outlines are placed before they are filled, and the surface and its below-surface
check are the placed part's.  Strokes are ordered for short travel.

A loop that ended ``needs_attention`` (its field's check failed: the verification points
disagree with the fit, the plan was too sparse for the learned prior) does not feed a
program by default: the submission is refused (422) naming the loop and its verdict, unless
the request says ``accept_unverified: true``; a program so accepted says so in its result
(``loop``: the loop's state, ``accepted_unverified`` and the verdict's reasons).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from pydantic import Field

from app.circuits.nets import Copper, area_polygon, check_nets, trace_copper
from app.circuits.opens import check_opens, fill_coverage
from app.circuits.program import Stroke, write_circuit_program
from app.circuits.strokes import fill_tip_strokes, trace_passes_many
from app.circuits.surface import PrintedPoints
from app.compensation.standoff import CompensationParams
from app.domain.errors import ConformaError, InvalidInput
from app.geometry.drape import drape_polyline
from app.jobs.circuit_surface import loop_placement, measured_surface
from app.jobs.form_hints import form
from app.jobs.gcode_meta import gcode_meta
from app.jobs.params import StandoffMm, standoff_of
from app.jobs.results.loop import ClosedLoopResult, LoopTrace
from app.jobs.results.models import CompensateResult, ProbeRunResult, compensate_rows
from app.jobs.results.program import CircuitProgramResult
from app.platform.models import CircuitImport, Job
from app.reconstruction.field_trust import with_bound
from app.runtime.context import JobContext
from app.runtime.reads import JobReads
from app.runtime.registry import JobParams, job_kind

#: slack (mm) below surface + standoff a printed point may come on a fitted field (the traces'
#: compensation samples the same field along its own curve); below the surface itself is
#: always refused (also on a surface interpolated between stations, which the traces'
#: per-trace reconstructions do not follow point for point)
SURFACE_TOLERANCE_MM = 0.002
_COMPENSATION = CompensationParams()  # without a machine: the compensated traces' dialect and dispenser


class CircuitProgramParams(JobParams):
    import_id: str = Field(description="a committed circuit import (POST /parts/{id}/circuits:import)")
    closed_loop_job_id: str = Field(description="a succeeded closed_loop over the import's traces")
    machine_id: str | None = Field(None, description="dialect and dispense codes from this machine's profile")
    line_width_mm: float = Field(0.2, gt=0.01, le=5, description="the nozzle's line: pass pitch and fill spacing")
    standoff_mm: StandoffMm | None = Field(None, description="pads and areas; default: the import's")
    feed_mm_min: float = Field(300.0, gt=0, le=100_000)
    clearance_mm: float = Field(2.0, gt=0, le=100, json_schema_extra=form(advanced=True))
    pads: bool = Field(True, description="fill pads and areas")
    net_clearance_mm: float = Field(0.0, ge=0, le=10, description="copper of different nets closer than this "
                                    "(top view) counts as a short; 0: only touching copper",
                                    json_schema_extra=form(advanced=True))
    accept_unverified: bool = Field(False, description="accept a closed loop that ended needs_attention (its "
                                    "field's check failed); refused otherwise", json_schema_extra=form(advanced=True))


def accepted_loop(loop: Job, accept_unverified: bool, error: type[ConformaError] = InvalidInput) -> Job:
    """``loop`` (a closed_loop job record) when it may feed a program: succeeded, or ended
    ``needs_attention`` and ``accept_unverified``; else ``error`` naming the loop, its state and
    (needs_attention) its verdict's reasons and verified line."""
    field = "params.closed_loop_job_id"
    if loop.kind == "closed_loop" and loop.status == "needs_attention":
        if accept_unverified:
            return loop
        verdict = (loop.result or {}).get("verdict") or {}
        reasons = "; ".join(verdict.get("reasons") or []) or "its field's check failed"
        raise error(f"closed loop {loop.id!r} ended needs_attention ({reasons}; "
                    f"{verdict.get('verified') or 'not verified'}): "
                    "its surface is not verified, so this program could put the nozzle off the real part. Run the "
                    "loop again (verdict.suggested_probe), or accept it explicitly with accept_unverified=true",
                    field=field, value=loop.id)
    if loop.kind != "closed_loop" or loop.status != "succeeded":
        raise error(f"job {loop.id!r} is a {loop.status} {loop.kind} job; a succeeded closed_loop job is needed",
                    field=field, value=loop.id)
    return loop


def operator_accepted(loop: Job) -> bool:
    """Whether an operator accepted the loop at its verification (``POST /jobs/{id}/accept``:
    it then ends succeeded, its verdict says ``accepted``)."""
    return bool(((loop.result or {}).get("verdict") or {}).get("accepted"))


def loop_state(loop: Job) -> dict:
    """What a program records of its loop: id, state, whether it was accepted unverified (by
    this request or by an operator at the loop's verification), and the verdict's reasons
    (empty when verified or without a field check)."""
    verdict = (loop.result or {}).get("verdict") or {}
    unverified = loop.status == "needs_attention" or operator_accepted(loop)
    return {"job_id": loop.id, "status": loop.status, "accepted_unverified": unverified,
            "reasons": list(verdict.get("reasons") or []) if unverified else []}


def _compensated(ctx: JobContext, entries: dict[str, LoopTrace],
                 trace_ids: list[str]) -> dict[str, tuple[Job, CompensateResult]]:
    """trace id -> (its compensate job, its typed row): each compensate job (a board job holds
    a batch of traces) read and parsed once, not once per trace it holds."""
    jobs: dict[str, tuple[Job, dict[str, CompensateResult]]] = {}
    out = {}
    for trace_id in trace_ids:
        job_id = entries[trace_id].compensate
        if job_id not in jobs:
            comp = ctx.job(job_id, kind="compensate", field="params.closed_loop_job_id")
            jobs[job_id] = (comp, compensate_rows(comp))                  # one-trace or board job
        comp, rows = jobs[job_id]
        out[trace_id] = (comp, rows[trace_id])
    return out


def _loop_entries(loop: Job) -> dict[str, LoopTrace]:
    return ClosedLoopResult.of(loop).by_trace()


def import_probe_trace_ids(reads: JobReads, imp: CircuitImport) -> list[str]:
    """The import's pad / area probe rings (traces with source.role pad_probe), oldest first."""
    return [t.id for t in reads.traces_of_part(imp.part_id)
            if (t.source or {}).get("import_id") == imp.id and (t.source or {}).get("role") == "pad_probe"]


def station_runs(entries: dict[str, LoopTrace], trace_ids: list[str]) -> list[str]:
    """The distinct probe runs (ids, first-seen order) behind ``trace_ids``: a joint loop probes
    every trace in one run, whose stations then count once, not once per trace."""
    runs = [entries[t].probe_run for t in trace_ids]
    if any(r is None for r in runs):
        raise InvalidInput("a circuit program reads the closed loop's probe runs; this loop measured by scanning "
                           "(measuring scan): print its traces' programs instead", field="params.closed_loop_job_id",
                           value=next(t for t, r in zip(trace_ids, runs) if r is None))
    return list(dict.fromkeys(r for r in runs if r is not None))


def stored_areas(areas: list) -> list[dict]:
    """An import's stored areas as dicts (name, source, exterior_xy_mm, holes_xy_mm, area_mm2);
    an area stored as its bare exterior ring (no holes, no source) is read as one."""
    out = []
    for i, a in enumerate(areas):
        if isinstance(a, dict):
            out.append(a)
        else:
            ring = a
            out.append({"name": f"area {i}", "source": {}, "exterior_xy_mm": ring, "holes_xy_mm": [],
                        "area_mm2": round(area_polygon(ring).area, 6)})
    return out


class ImportTrace(NamedTuple):
    """What the net checks read of an import's trace: name, net, width (mm or None) and its
    stored nominal's top view xy (n, 2) mm."""

    name: str
    net: str
    width_mm: float | None
    xy: np.ndarray


def import_traces(reads: JobReads, imp: CircuitImport) -> dict[str, ImportTrace]:
    """{trace id: :class:`ImportTrace`} of the import's stored traces, read once for both net
    checks (the columns they use; the nominal's points as stored, which
    :meth:`TracePolyline.to_dict` wrote valid)."""
    return {t.id: ImportTrace(t.name, str((t.source or {}).get("net") or ""), t.width_mm,
                              np.asarray(t.nominal["points"], dtype=float)[:, :2])
            for t in reads.trace_summaries(imp.trace_ids)}


def import_copper(reads: JobReads, imp: CircuitImport, pads: bool,
                  traces: dict[str, ImportTrace] | None = None) -> list[Copper]:
    """The copper a circuit program prints: the import's traces at their width, and (with
    ``pads``) its on-part pads and its areas with their holes; top view, mm, with their nets.
    ``traces``: :func:`import_traces` when already read."""
    rows = import_traces(reads, imp) if traces is None else traces
    copper = [Copper("trace", t.name, t.net, trace_copper(t.xy, t.width_mm or 0.0)) for t in rows.values()]
    if pads:
        copper += [Copper("pad", p["name"], str((p.get("source") or {}).get("net") or ""),
                          area_polygon(p["outline_xy_mm"])) for p in imp.pads if p["on_part"]]
        copper += [Copper("area", a["name"], str((a.get("source") or {}).get("net") or ""),
                          area_polygon(a["exterior_xy_mm"], a["holes_xy_mm"])) for a in stored_areas(imp.areas)]
    return copper


def printed_copper(reads: JobReads, imp: CircuitImport, line_width_mm: float, fills: bool,
                   traces: dict[str, ImportTrace] | None = None) -> tuple[list[Copper], list[list[int]]]:
    """The copper as printed (traces at max(width, line), on-part pads and areas as their fills
    cover them when ``fills``, else as drawn) and the source's connected pieces of each named
    net (the files' stored ``connections``) as indices into it.  ``traces``:
    :func:`import_traces` when already read."""
    rows = import_traces(reads, imp) if traces is None else traces
    copper: list[Copper] = []
    where: dict[tuple[str, int], int] = {}

    def add(kind: str, index: int, item: Copper) -> None:
        where[(kind, index)] = len(copper)
        copper.append(item)

    for g, trace_id in enumerate(imp.trace_ids):
        t = rows.get(trace_id)
        if t is not None:
            add("traces", g, Copper("trace", t.name, t.net, trace_copper(t.xy, max(t.width_mm or 0.0, line_width_mm))))
    for g, p in enumerate(imp.pads):
        if p["on_part"]:
            shape = fill_coverage(p["outline_xy_mm"], [], line_width_mm) if fills else area_polygon(p["outline_xy_mm"])
            add("pads", g, Copper("pad", p["name"], str((p.get("source") or {}).get("net") or ""), shape))
    for g, a in enumerate(stored_areas(imp.areas)):
        shape = (fill_coverage(a["exterior_xy_mm"], a["holes_xy_mm"], line_width_mm) if fills
                 else area_polygon(a["exterior_xy_mm"], a["holes_xy_mm"]))
        add("areas", g, Copper("area", a["name"], str((a.get("source") or {}).get("net") or ""), shape))
    pieces: list[list[int]] = []
    base = {"traces": 0, "pads": 0, "areas": 0}
    for f in imp.files:
        for c in f.get("connections") or []:
            pieces.append([where[(kind, base[kind] + k)] for kind in base for k in c.get(kind, [])
                           if (kind, base[kind] + k) in where])
        for kind in base:
            base[kind] += int(f.get(kind, 0))
    return copper, pieces


def _check(params: CircuitProgramParams, reads: JobReads) -> None:
    imp = reads.circuit_import(params.import_id, field="params.import_id")
    traces = import_traces(reads, imp)
    check_nets(import_copper(reads, imp, params.pads, traces), params.net_clearance_mm, field="params.import_id")
    check_opens(*printed_copper(reads, imp, params.line_width_mm, params.pads, traces), field="params.import_id")
    loop = accepted_loop(reads.job(params.closed_loop_job_id, field="params.closed_loop_job_id"),
                         params.accept_unverified)
    entries = _loop_entries(loop)                        # the loop's result read once, not once per trace
    missing = [t for t in imp.trace_ids if t not in entries]
    if missing:
        raise InvalidInput(f"the closed loop did not compensate trace {missing[0]!r} of the import",
                           field="params.closed_loop_job_id", value=missing[0])
    unprobed = [t for t in import_probe_trace_ids(reads, imp) if t not in entries] if params.pads else []
    if unprobed:
        raise InvalidInput(f"the closed loop did not probe the pad ring {unprobed[0]!r} of the import: give it the "
                           "import's probe_trace_ids too (or pads=false)", field="params.closed_loop_job_id",
                           value=unprobed[0])


@job_kind("circuit_program", CircuitProgramParams, check=_check,
          references=lambda p: [("job", p.closed_loop_job_id)] + ([("machine", p.machine_id)] if p.machine_id else []))
def run(ctx: JobContext, params: CircuitProgramParams) -> dict:
    """One program for the whole circuit; artifact ``circuit.gcode``."""
    with ctx.reads() as reads:
        imp = reads.circuit_import(params.import_id, field="params.import_id")
        probe_ids = import_probe_trace_ids(reads, imp) if params.pads else []
        traces = import_traces(reads, imp)
        nets = check_nets(import_copper(reads, imp, params.pads, traces), params.net_clearance_mm,
                          field="params.import_id")
        pieces = check_opens(*printed_copper(reads, imp, params.line_width_mm, params.pads, traces),
                             field="params.import_id")
    loop = accepted_loop(ctx.job(params.closed_loop_job_id, field="params.closed_loop_job_id"),
                         params.accept_unverified, ConformaError)
    entries = _loop_entries(loop)
    placement = loop_placement(ctx, entries, imp.trace_ids)          # part -> machine, as the traces
    mesh = ctx.placed_mesh(ctx.part(imp.part_id), placement)

    stations: list[list[float]] = []
    deviations: list[float] = []
    runs = station_runs(entries, probe_ids + list(imp.trace_ids))      # each probe run once
    for run_id in runs:
        probe = ctx.job(run_id, kind="probe_run", field="params.closed_loop_job_id")
        for pt in ProbeRunResult.of(probe).points:
            stations.append(pt.nominal[:2])
            deviations.append(pt.measured[2] - pt.nominal[2])
    surface, check = measured_surface(ctx, mesh, entries, imp.trace_ids, runs, stations, deviations, placement)
    bound = ((loop.result or {}).get("verdict") or {}).get("bound_mm")
    if check is not None and bound is not None:
        check = with_bound(check, [float(bound)])          # the traces' bound the loop's verdict stated
    if check is not None and check.needs_attention and not (params.accept_unverified or operator_accepted(loop)):
        raise ConformaError(f"the field of closed loop {loop.id!r} needs attention ({'; '.join(check.reasons)}): "
                            "accept it explicitly with accept_unverified=true", field="params.closed_loop_job_id",
                            value=loop.id)
    printed = PrintedPoints(surface)

    def surface_z(xy: np.ndarray) -> np.ndarray:
        return surface.at(xy)[0]

    standoff = standoff_of(params.standoff_mm, imp.options.get("standoff_mm"))
    strokes: list[Stroke] = []
    with ctx.reads() as reads:                                    # every trace in one query
        records = reads.traces_by_id(imp.trace_ids)
    compensated = _compensated(ctx, entries, imp.trace_ids)
    tips = [np.asarray(compensated[t][1].points, float) for t in imp.trace_ids]
    passes = trace_passes_many(tips, [records[t].width_mm or params.line_width_mm for t in imp.trace_ids],
                               params.line_width_mm, surface_z)             # one surface evaluation for all
    for trace_id, trace_passes_ in zip(imp.trace_ids, passes):
        record = records[trace_id]
        comp = compensated[trace_id][0]
        for k, p in enumerate(trace_passes_):
            strokes.append(Stroke(p, "trace" if k == 0 else "pass", record.name,
                                  record.feed_mm_min or params.feed_mm_min))
            printed.add(record.name, "trace", p, standoff_of(comp.params.get("standoff_mm"), record.standoff_mm))
    ctx.progress(0.5, "filling pads and areas")
    fills = 0
    if params.pads and (imp.pads or imp.areas):
        def drape(xy: np.ndarray) -> np.ndarray:
            return drape_polyline(mesh, xy).points

        def placed(xy: list) -> np.ndarray:                               # part -> machine, top view
            ring = np.asarray(xy, float).reshape(-1, 2)
            return ring if placement is None else placement.apply(ring)

        angle = 0.0 if placement is None else placement.rz_deg              # rasters stay along the part's x
        outlines: list[tuple[Any, Any, str, str]] = [(p["outline_xy_mm"], [], p["name"], "pad") for p in imp.pads
                                                     if p["on_part"]]
        outlines += [(a["exterior_xy_mm"], a["holes_xy_mm"], a["name"], "area") for a in stored_areas(imp.areas)]
        for ring, holes, name, kind in outlines:
            for s in fill_tip_strokes(placed(ring), [placed(h) for h in holes],
                                      params.line_width_mm, drape, surface_z, standoff, angle_deg=angle):
                strokes.append(Stroke(s, kind, name, params.feed_mm_min))
                printed.add(name, kind, s, standoff)
                fills += 1
    low = printed.below(SURFACE_TOLERANCE_MM if check is not None else np.inf)
    if low:
        name, clearance, item_standoff = low[0]
        raise InvalidInput(f"{len(low)} printed item(s) would put the nozzle below the measured surface plus their "
                           f"standoff: {name!r} comes to {clearance * 1000:.1f} um over it (standoff "
                           f"{item_standoff * 1000:.1f} um)", field="params.closed_loop_job_id",
                           value=params.closed_loop_job_id)
    if not strokes:
        raise InvalidInput("the import has nothing to print", field="params.import_id", value=params.import_id)
    dialect, (on, off) = _COMPENSATION.dialect, _COMPENSATION.dispense  # without a machine: the dialect's own
    if params.machine_id:
        machine = ctx.machine(params.machine_id)
        dialect, on, off = machine.dialect, machine.profile["dispense_on"], machine.profile["dispense_off"]
    program = write_circuit_program(strokes, dialect=dialect, dispense_on=on, dispense_off=off,
                                    clearance_mm=params.clearance_mm, part_top_mm=float(mesh.bounds[1][2]),
                                    job_id=ctx.job_id)
    ctx.artifact("circuit.gcode", program.text.encode(), "text/x-gcode", gcode_meta(program.text))
    return CircuitProgramResult.written({"strokes": program.strokes, "traces": len(imp.trace_ids),
                                         "fill_strokes": fills,
            "pad_probe_traces": probe_ids, "nets_checked": nets,
            "stations": len(stations) if check is None else len(check.fit.stations.xy),  # every round's, once
            "connections_checked": pieces, "loop": loop_state(loop),
            "travel_mm": round(program.travel_mm, 3), "travel_input_order_mm": round(program.travel_input_order_mm, 3),
            "order": [[i, r] for i, r in program.order], "dispense_on": on, "dispense_off": off,
            "surface": {"model": "field" if check is not None else "stations",
                        "placement": None if placement is None else placement.to_dict(),
                        "verified": None if check is None else check.verified_line(),
                        "needs_attention": None if check is None else check.needs_attention,
                        **printed.as_dict()}})
