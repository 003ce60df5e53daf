"""Circuit import: ECAD files (KiCad, Gerber + Excellon, DXF, SVG) placed on a part.

``POST /api/v1/parts/{part_id}/circuits:import`` — multipart ``files`` (one or more) and an
``options`` JSON form field.  All or nothing: every trace of every file is draped like a
trace created by ``POST /parts/{id}/traces`` (the same code path), and either all are stored
or none.  ``dry_run`` returns the mapped circuit and its warnings and stores nothing.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Any, Literal

import anyio
import numpy as np
from fastapi import APIRouter, File, Form, Query, Request, UploadFile
from pydantic import BaseModel, Field, ValidationError
from pydantic.dataclasses import dataclass as pydantic_dataclass

from app.api.circuit_pages import paged
from app.api.deps import Operator, RuntimeDep, SessionDep, Viewer
from app.api.limits import lone_surrogate_path
from app.api.routes.traces import trace_out
from app.api.schemas import Finite, Strict, TraceCreate, UtcDatetime
from app.circuits.mapping import MappingOptions
from app.circuits.nets import area_polygon
from app.circuits.pad_probes import probe_ring
from app.compensation.standoff import DEFAULT_STANDOFF_MM
from app.domain.errors import ConformaError, InvalidInput
from app.jobs.circuit_import import FileFacts, ImportMapped, ImportRequest, PartMesh, read_and_map
from app.jobs.kinds.circuit_program import import_probe_trace_ids, stored_areas
from app.parts.traces import DrapedAhead
from app.platform.lookup import get_or_404
from app.platform.models import CircuitImport, Part, Trace, new_id, utcnow
from app.runtime.isolated import call_isolated
from app.runtime.reads import JobReads

router = APIRouter(prefix="/api/v1", tags=["circuits"])
MAX_FILES = 20


class CircuitImportOptions(Strict):
    """How to read the files and lay the circuit on the part (mm, degrees)."""

    format: Literal["kicad", "gerber", "excellon", "dxf", "svg"] | None = Field(
        None, description="auto-detected from the name and content when omitted")
    layers: list[str] | None = Field(None, max_length=50, description="KiCad copper layer (one; default F.Cu), "
                                     "DXF layers, SVG group ids/labels; default all")
    origin_mm: list[Finite] | None = Field(None, min_length=2, max_length=2,
                                           description="top-view point (mm) where the anchor lands, the wrap's "
                                                       "centre; default: the middle of the part's top view "
                                                       "(anchor board_center) or (0, 0) (file_origin)")
    anchor: Literal["board_center", "file_origin"] | None = Field(
        None, description="the layout point put on origin_mm: the board's centre (its outline's, else its "
                          "copper's bounding box; the default without origin_mm) or the file's (0, 0) (the "
                          "default with origin_mm)")
    rotation_deg: Finite = 0.0
    mirror: bool = Field(False, description="mirror the layout in x (bottom layers)")
    mapping: Literal["project", "wrap"] = "project"
    max_stretch: Finite = Field(1.01, ge=1.0, le=10.0, description="warn above this stretch")
    standoff_mm: Finite = Field(DEFAULT_STANDOFF_MM, gt=0, le=50)
    feed_mm_min: Finite | None = Field(None, gt=0, le=100_000)
    layer: str | None = Field(None, max_length=40, description="the copper layer printed: top (the default), "
                              "bottom, inner<n> or a KiCad layer name; the others are reported in files[].stack")
    copper_graphics: bool = Field(False, description="print a KiCad board's copper graphics (polygons, "
                                  "rectangles, circles, lines) and text as copper; off: they are reported in warnings")
    dry_run: bool = False
    view_id: str | None = Field(None, min_length=1, max_length=40, pattern=r"^[A-Za-z0-9_-]+$",
                                description="with dry_run: draw the mapped circuit on the part in this 3-D view "
                                            "(from POST /viewer/token) before accepting")


@pydantic_dataclass(frozen=True)
class ImportedFile(FileFacts):
    """One file of the import as read: its format, units, layers, the reader's notes and its counts."""


class ImportedTrace(BaseModel):
    index: int
    name: str
    source: dict[str, Any]
    layout_length_mm: float
    length_mm: float | None
    stretch: float | None
    on_part: bool
    trace: dict[str, Any] | None = Field(None, description="the stored trace (or, on a dry run, what it would be)")


class ImportedPad(BaseModel):
    name: str
    shape: str
    source: dict[str, Any]
    center_mm: list[float | None]
    outline_xy_mm: list[list[float]]
    on_part: bool
    probe_trace_id: str | None = Field(None, description="the trace whose probes cover this pad")


class ImportedArea(BaseModel):
    name: str
    source: dict[str, Any] = Field(default_factory=dict, description="file, layer, net (\"\" when the file "
                                   "names none), entity")
    exterior_xy_mm: list[list[float]]
    holes_xy_mm: list[list[list[float]]] = Field(default_factory=list, description="rings inside the area that "
                                                 "are not copper (around other nets' pads and tracks): never filled")
    area_mm2: float = Field(0.0, description="the copper area (exterior minus holes, top view)")


class CircuitImportOut(BaseModel):
    import_id: str
    dry_run: bool
    files: list[ImportedFile]
    traces: list[ImportedTrace]
    pads: list[ImportedPad]
    areas: list[ImportedArea]
    probe_paths: list[dict[str, Any]] = Field(default_factory=list, description=(
        "a closed probe ring inside every on-part pad and area (stored as traces with source.role "
        "pad_probe): give probe_trace_ids to the closed loop with the import's traces so the fills "
        "are compensated from stations on them"))
    probe_trace_ids: list[str] = Field(default_factory=list)
    vias: list[dict[str, Any]] = Field(default_factory=list, description="every via: center_mm on the part, "
                                       "diameter_mm, drill_mm, net, layers, on_part, file")
    outline: list[list[list[float]]] = Field(default_factory=list, description="the board's edge (KiCad "
                                             "Edge.Cuts, a Gerber profile) as rings in the top view, mm")
    warnings: list[dict[str, Any]]
    placement: dict[str, Any] = Field(default_factory=dict, description="where the layout landed: origin_mm "
                                      "(top view), anchor and anchor_mm (the layout point put there)")
    preview: dict[str, Any] | None = Field(None, description="with dry_run and view_id: the 3-D view drawn "
                                           "(view_id, generation, nodes) or why it could not be")
    totals: dict[str, int] = Field(default_factory=dict, description="every list's full length: traces, pads, "
                                   "areas, warnings, vias, probe_paths, outline (the lists hold the rows offset .. "
                                   "offset + limit when the request gives them)")


class CircuitImportRecord(BaseModel):
    id: str
    part_id: str
    files: list[dict[str, Any]]
    options: dict[str, Any]
    trace_ids: list[str]
    pads: list[dict[str, Any]]
    areas: list[ImportedArea]
    probe_trace_ids: list[str] = Field(default_factory=list, description="the pads' and areas' probe rings")
    created_at: UtcDatetime


def _options(raw: str) -> CircuitImportOptions:
    try:
        parsed = json.loads(raw or "{}")
        bad = lone_surrogate_path(parsed)
        if bad is not None or lone_surrogate_path(raw) is not None:
            loc = ".".join(["options", *(bad or ())])
            raise InvalidInput(f"{loc} holds a lone UTF-16 surrogate (not valid Unicode)", field=loc,
                               value=None)
        return CircuitImportOptions.model_validate(parsed)
    except json.JSONDecodeError as exc:
        raise InvalidInput(f"options is not JSON: {exc.msg} at column {exc.colno}", field="options",
                           value=raw[:80]) from None
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(["options", *map(str, err["loc"])])
        raise InvalidInput(f"{loc}: {err['msg']}", field=loc, value=err.get("input")) from None


def _file_name(upload: UploadFile) -> str:
    return (upload.filename or "circuit").rsplit("/", 1)[-1]


def _finite(v: float) -> float | None:
    return None if v != v else round(float(v), 6)


@router.post("/parts/{part_id}/circuits:import", status_code=201, dependencies=[Operator])
def import_circuit(part_id: str, runtime: RuntimeDep, session: SessionDep, request: Request,
                   files: Annotated[list[UploadFile], File(description="circuit files (KiCad, Gerber, Excellon, "
                                                                       "DXF, SVG)")],
                   options: Annotated[str, Form(description="CircuitImportOptions as JSON")] = "{}",
                   offset: Annotated[int, Query(ge=0, description="first row of every list in the answer")] = 0,
                   limit: Annotated[int | None, Query(ge=1, le=100_000, description="rows of every list in the "
                                                      "answer (all when omitted); totals gives their lengths")] = None,
                   ) -> CircuitImportOut:
    """Import circuits onto a part: all files' traces are stored, or none (422 naming the file's
    line or entity, or the trace); ``dry_run`` stores nothing."""
    opts = _options(options)
    part = get_or_404(session, Part, part_id)
    if len(files) > MAX_FILES:
        raise InvalidInput(f"at most {MAX_FILES} files per import", field="files", value=len(files))
    mesh = runtime.meshes.mesh(part)
    anchor = opts.anchor or ("file_origin" if opts.origin_mm is not None else "board_center")
    origin = opts.origin_mm if opts.origin_mm is not None else (
        mesh.bounds[:, :2].mean(axis=0).tolist() if anchor == "board_center" else [0.0, 0.0])
    read_all = _read_and_map(runtime, request, part, files, opts, (float(origin[0]), float(origin[1])), anchor)
    placement = read_all.placement
    import_id = new_id("cimp")
    out = CircuitImportOut(import_id=import_id, dry_run=opts.dry_run, files=[], traces=[], pads=[], areas=[],
                           warnings=[])
    records: list = []
    pad_records: list = []
    ring_names: dict[str, int] = {}
    out.placement = {"origin_mm": [round(float(v), 6) for v in placement.origin_mm], "anchor": anchor,
                     "anchor_mm": [round(float(v), 6) for v in placement.anchor_mm]}
    firsts = np.cumsum([0] + [len(read.mapped.areas) for read in read_all.files]).tolist()
    rings = [[probe_ring(outline, list(holes)) for _what, outline, holes in _ring_outlines(read.mapped, first)]
             for read, first in zip(read_all.files, firsts)]  # per file, in _ring_outlines' order
    ahead = DrapedAhead(runtime.meshes, part, [
        _xy_geometry(mt.geometry) for read in read_all.files for mt in read.mapped.traces if mt.on_part]
        + [_xy_geometry({"type": "polyline", "points": r.tolist()}) for file in rings for r in file if r is not None])
    for file_rings, read in zip(rings, read_all.files):
        name, mapped = read.facts.file, read.mapped
        out.files.append(ImportedFile(**asdict(read.facts)))
        out.vias += [dict(v, file=name) for v in mapped.vias]
        out.outline += [r.round(6).tolist() for r in mapped.outline]
        base = len(out.traces)
        for w in mapped.warnings:
            w = dict(w, file=name)
            if "traces" in w:
                w["traces"] = [base + i for i in w["traces"]]
            out.warnings.append(w)
        for mt in mapped.traces:
            index = base + mt.index
            label = f"{name}:{mt.source['entity']}"[:200]
            item = ImportedTrace(index=index, name=label, source=mt.source, layout_length_mm=mt.layout_length_mm,
                                 length_mm=_finite(mt.length_mm), stretch=_finite(mt.stretch), on_part=mt.on_part)
            out.traces.append(item)
            if not mt.on_part:
                continue
            body = TraceCreate(name=label, geometry=mt.geometry, frame="xy", standoff_mm=opts.standoff_mm,
                               width_mm=mt.source["width_mm"] or None, feed_mm_min=opts.feed_mm_min)
            try:
                trace = ahead.build(runtime.meshes, part, body, field_prefix=f"traces.{index}")
            except ConformaError as exc:
                if opts.dry_run:
                    out.warnings.append({"kind": "leaves_part", "traces": [index], "file": name,
                                         "message": exc.message, "value": exc.value})
                    item.on_part = False
                    continue
                exc.message = f"{label}: {exc.message}"
                raise
            trace.source = {**mt.source, "import_id": import_id, "mapping": opts.mapping,
                            "stretch": _finite(mt.stretch), "layout_length_mm": mt.layout_length_mm}
            records.append((item, trace))
        for p in mapped.pads:
            out.pads.append(ImportedPad(name=p.name, shape=p.shape, source=p.source,
                                        center_mm=[_finite(v) for v in p.center],
                                        outline_xy_mm=p.outline_xy.round(6).tolist(), on_part=p.on_part))
        first_area = len(out.areas)
        out.areas += [ImportedArea(name=f"area {first_area + i}", source=a.source,
                                   exterior_xy_mm=a.exterior_xy.round(6).tolist(),
                                   holes_xy_mm=[h.round(6).tolist() for h in a.holes_xy],
                                   area_mm2=round(area_polygon(a.exterior_xy, a.holes_xy).area, 6))
                      for i, a in enumerate(mapped.areas)]
        pads = [out.pads[len(out.pads) - len(mapped.pads) + i] for i, p in enumerate(mapped.pads) if p.on_part]
        outlines = _ring_outlines(mapped, first_area)
        for pad, (what, _outline, _holes), ring in zip(pads + [None] * len(mapped.areas), outlines, file_rings):
            label = _unique(f"{name}:{what}", ring_names)  # two pads of one footprint may share a number
            probe = _probe_trace(runtime, part, ring, label, opts, import_id, out, records, ahead)
            if pad is not None and probe is not None:
                pad_records.append((pad, probe))
    if not opts.dry_run:
        off = [t for t in out.traces if not t.on_part]
        if off:
            first = off[0]
            raise InvalidInput(f"{first.name}: the trace leaves the part's upper surface (use a dry run to see "
                               "every warning)", field=f"traces.{first.index}", value=first.source.get("entity"))
        session.add_all([trace for _, trace in records])
        for pad, trace in pad_records:
            pad.probe_trace_id = trace.id
        out.probe_trace_ids = [t.id for item, t in records if item is None]
        session.add(CircuitImport(
            id=import_id, part_id=part.id,
            files=[dict(asdict(f), connections=r.connections, interconnects=r.mapped.vias)
                                                  for f, r in zip(out.files, read_all.files)],
            options=opts.model_dump(), trace_ids=[trace.id for item, trace in records if item is not None],
            pads=[p.model_dump() for p in out.pads], areas=[a.model_dump() for a in out.areas],
            created_at=utcnow()))
        session.commit()
    for item, trace in records:
        if item is None:
            continue
        item.trace = trace_out(trace).model_dump(mode="json") if not opts.dry_run else {
            "id": None, "name": trace.name, "length_mm": trace.length_mm, "z_range": [trace.z_min, trace.z_max],
            "width_mm": trace.width_mm, "geometry": trace.geometry, "nominal": {"points": _nominal_points(trace)}}
    if opts.dry_run and opts.view_id:
        out.preview = _preview(request, part, mesh, out, opts.view_id)
    out.totals = paged(out, offset, limit)
    return out


def _read_and_map(runtime, request: Request, part: Part, files: list[UploadFile], opts: CircuitImportOptions,
                  origin_mm: tuple[float, float], anchor: str) -> ImportMapped:
    """Every file read and mapped in a bounded child process (:mod:`app.jobs.circuit_import`):
    CONFORMA_JOB_MEMORY_MB of memory, CONFORMA_IMPORT_TIME_S of time, killed when the client
    goes away.  The uploads reach it as spooled files, never as copies in this process."""
    settings = runtime.settings
    with tempfile.TemporaryDirectory(prefix="import-", dir=settings.data_dir) as tmp:
        paths = []
        for k, upload in enumerate(files):
            path = Path(tmp) / str(k)
            with path.open("wb") as spool:
                shutil.copyfileobj(upload.file, spool, 2**20)
            paths.append((_file_name(upload), str(path)))
        job = ImportRequest(paths, opts.format, opts.layers, origin_mm, opts.rotation_deg, opts.mirror, anchor,
                            MappingOptions(opts.mapping, opts.max_stretch), PartMesh(part.sha256, part.format),
                            graphics=opts.copper_graphics, copper_layer=opts.layer)
        result: ImportMapped = call_isolated(
            read_and_map, job, settings, memory_bytes=int(settings.job_memory_mb * 2**20),
            time_s=settings.import_time_s, what="the import",
            cancelled=lambda: bool(anyio.from_thread.run(request.is_disconnected)))
        return result


def _nominal_points(trace: Trace) -> list[list[float]]:
    """The trace's stored nominal points [[x, y, z]] mm (as :class:`TracePolyline` stored them)."""
    points: list[list[float]] = trace.nominal["points"]  # stored by TracePolyline.to_dict: read back, the same
    return points


def _preview(request: Request, part: Part, mesh, out: CircuitImportOut, view_id: str) -> dict[str, Any]:
    """Draw the dry run in the 3-D view ``view_id`` (see :mod:`app.viewer.circuit_preview`)."""
    viewer = getattr(request.app.state, "viewer", None)
    if viewer is None:
        return {"view_id": view_id, "drawn": False, "reason": "the 3D view is off on this server"}
    from app.viewer.circuit_preview import circuit_preview_scene

    snapshot = viewer.show(circuit_preview_scene(part.id, mesh, out.model_dump(mode="json")), view_id)
    return {"view_id": view_id, "drawn": True, "generation": snapshot["generation"], "nodes": snapshot["nodes"],
            "notes": snapshot["notes"]}


def _unique(label: str, seen: dict[str, int]) -> str:
    """``label``, or ``label #k`` when it was given k - 1 times before in this import."""
    seen[label] = seen.get(label, 0) + 1
    return label if seen[label] == 1 else f"{label} #{seen[label]}"


def _ring_outlines(mapped, first_area: int) -> list[tuple[str, Any, Any]]:
    """(what, outline (n, 2), holes) of each pad on the part and each area of a mapped file
    (named from ``first_area``, the import's count of areas before it), in that order: what
    gets a probe ring."""
    return ([(p.name, p.outline_xy, []) for p in mapped.pads if p.on_part]
            + [(f"area {first_area + i}", a.exterior_xy, a.holes_xy) for i, a in enumerate(mapped.areas)])


def _xy_geometry(geometry: dict[str, Any]) -> dict[str, Any]:
    """A top-view geometry as the API reads it (the form :class:`DrapedAhead` keys on)."""
    return TraceCreate(name="x", geometry=geometry, frame="xy").geometry.model_dump()


def _probe_trace(runtime, part: Part, ring, label: str, opts: CircuitImportOptions, import_id: str,
                 out: CircuitImportOut, records: list, ahead: DrapedAhead) -> Trace | None:
    """The probe ring (m, 2) of a pad or area (None: too small for one) as a trace (records gets
    (None, trace)); a ring the part cannot carry is a warning, the pad is then filled from the
    stations around it."""
    if ring is None:
        return None
    body = TraceCreate(name=f"{label} (pad probe)"[:200], geometry={"type": "polyline", "points": ring.tolist()},
                       frame="xy", standoff_mm=opts.standoff_mm)
    try:
        trace = ahead.build(runtime.meshes, part, body, field_prefix="probe_paths")
    except ConformaError as exc:
        out.warnings.append({"kind": "pad_not_probed", "pad": label, "message": exc.message})
        return None
    trace.source = {"role": "pad_probe", "import_id": import_id, "pad": label}
    out.probe_paths.append({"pad": label, "ring_xy_mm": ring.round(6).tolist(),
                            "points": _nominal_points(trace)})
    records.append((None, trace))
    return trace


@router.get("/circuit-imports/{import_id}", dependencies=[Viewer])
def get_circuit_import(import_id: str, session: SessionDep) -> CircuitImportRecord:
    """A committed import: its files, options, trace ids, mapped pads and areas, and their probe traces."""
    imp = get_or_404(session, CircuitImport, import_id, field="import_id")
    record = imp.model_dump()
    record["areas"] = [ImportedArea(**a) for a in stored_areas(imp.areas)]
    return CircuitImportRecord(**record, probe_trace_ids=import_probe_trace_ids(JobReads(session), imp))
