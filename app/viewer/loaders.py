"""Build the :class:`FocusScene` of a part or a job from the stored records.

Reads the database and the blob store through the runtime (never over HTTP): job
records, their results and artifacts.  One function per job kind; a kind without its
own loader still shows its part and every G-code artifact as a toolpath.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import Any, NamedTuple

import numpy as np
from sqlmodel import Session, col, select

from app.domain.errors import NotFound
from app.gcode.lines import GcodeReadError
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_surface import NurbsSurface
from app.jobs.inputs import nominal_of
from app.jobs.results.models import (
    CompensateResult,
    ProbePlanResult,
    ProbeRunResult,
    ProgramEcho,
    ReconstructResult,
    SurfaceFitResult,
    compensate_rows,
    joint_trace_ranges,
    program_artifacts,
    reconstruct_rows,
)
from app.platform.lookup import get_or_404
from app.platform.models import COMPLETED_STATES, Artifact, Job, JobReference, Part, Trace
from app.probing.field_stored import stored_field
from app.probing.field_top import field_sd_surface
from app.viewer.deviation_map import ribbon_surface, standoff_errors
from app.viewer.gcode_paths import GcodeViewError
from app.viewer.offload import ParsePool
from app.viewer.program_scenes import PROGRAM_SCENES, print_scene
from app.viewer.residual_map import residual_map
from app.viewer.scene_data import (
    AxisGlyphs,
    DeviationPlot,
    FocusScene,
    HeightStack,
    LayerStack,
    Polyline,
    ProbeSet,
    ScalarSurface,
    SurfaceMesh,
    Toolpath,
)
from app.viewer.trace_math import project_onto_polyline, rings_to_segments

CURVE_SAMPLES = 400
MAX_FIELD_POLYLINES = 200
MAX_COLORED_MOVES = 200_000  # programs longer than this are drawn in their role's colour only


BOARD_DRAWN = 100  # traces of a board reconstruct / compensate job drawn in the 3-D view
MAX_MEASURED_MAPS = 20  # measured maps of a jetting_run shown in the 3-D view


def _ribbon(trace: Trace | None, samples: np.ndarray, label: str) -> tuple[ScalarSurface, ...]:
    """The rebuilt deviation of ``trace`` (samples (n, 2): s mm, dz mm) as a ribbon on the part:
    about 4 % of the trace's extent wide (0.5..4 mm), lifted 10 um off the nominal top."""
    if trace is None or len(samples) < 2:
        return ()
    nominal = nominal_of(trace).points
    width = float(np.clip(0.04 * np.ptp(nominal[:, :2], axis=0).max(), 0.5, 4.0))
    surface = ribbon_surface(f"{label} deviation", nominal, samples[:, 0], samples[:, 1], width, 0.01)
    return (surface,) if surface is not None else ()


class TraceRange(NamedTuple):
    """One trace's points [first, stop) of a joint probe plan / run."""

    trace_id: str
    trace: Trace | None
    name: str
    first: int
    stop: int


class Loader:
    """Loads scenes from one runtime (engine + blobs + mesh cache)."""

    def __init__(self, runtime: Any, parser: ParsePool | None = None) -> None:
        self.runtime = runtime
        self.parser = parser or ParsePool()

    # public --------------------------------------------------------------------------
    def part_scene(self, part_id: str) -> FocusScene:
        with Session(self.runtime.engine) as session:
            part = get_or_404(session, Part, part_id)
            traces = session.exec(select(Trace).where(col(Trace.part_id) == part_id)
                                  .order_by(col(Trace.created_at))).all()
            vertices, faces = self._mesh(part)
            lines = tuple(Polyline(t.name, nominal_of(t).points) for t in traces)
        return FocusScene({"part_id": part_id}, f"part {part.name}", vertices, faces, polylines=lines)

    def job_scene(self, job_id: str) -> FocusScene:
        with Session(self.runtime.engine) as session:
            job = get_or_404(session, Job, job_id)
            part = self._part_of(session, job)
            vertices, faces = self._mesh(part) if part is not None else (None, None)
            base = FocusScene({"job_id": job_id, "part_id": part.id if part else None},
                              f"{job.kind} {job.id} ({job.status})", vertices, faces)
            if job.status not in COMPLETED_STATES and job.kind != "print":  # a print shows its program while it runs
                return replace(base, notes=(f"job is {job.status}: {job.message}",))
            try:
                content = self._content(session, job)
            except GcodeReadError as exc:   # a program the view refuses to draw (its arcs' chords...)
                return replace(base, notes=(f"cannot draw this job's program {exc.message}",))
        if vertices is not None and content.part_matrix is not None:   # the part into the program's frame
            matrix = np.asarray(content.part_matrix, float)
            vertices = vertices @ matrix[:3, :3].T + matrix[:3, 3]
        return replace(content, focus=base.focus, title=base.title, mesh_vertices=vertices, mesh_faces=faces)

    # records ---------------------------------------------------------------------------
    def _mesh(self, part: Part) -> tuple[np.ndarray, np.ndarray]:
        mesh = self.runtime.meshes.mesh(part)
        return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)

    def _part_of(self, session: Session, job: Job, depth: int = 0) -> Part | None:
        """The part a job works on: directly, through a trace or through a job it reads."""
        refs = session.exec(select(JobReference).where(JobReference.job_id == job.id)).all()
        for ref in sorted(refs, key=lambda r: {"part": 0, "trace": 1}.get(r.ref_kind, 2)):
            if ref.ref_kind == "part":
                part = session.get(Part, ref.ref_id)
            elif ref.ref_kind == "trace":
                trace = session.get(Trace, ref.ref_id)
                part = session.get(Part, trace.part_id) if trace else None
            elif ref.ref_kind == "job" and depth < 4:
                other = session.get(Job, ref.ref_id)
                part = self._part_of(session, other, depth + 1) if other else None
            else:
                part = None
            if part is not None:
                return part
        return None

    def _artifact(self, session: Session, job_id: str, name: str) -> bytes | None:
        row = self._artifact_row(session, job_id, name)
        return None if row is None else self.runtime.blobs.read(row.sha256)

    def _artifact_row(self, session: Session, job_id: str, name: str) -> Artifact | None:
        return session.exec(select(Artifact).where(Artifact.job_id == job_id, Artifact.name == name)).first()

    def _program(self, session: Session, job: Job, name: str) -> Any:
        """The parsed moves of G-code artifact ``name`` (None when the job has none)."""
        row = self._artifact_row(session, job.id, name)
        if row is None:
            return None
        try:
            return self.parser.parse(self.runtime.blobs.read(row.sha256), *_dispense_lines(job), key=row.sha256)
        except GcodeReadError as exc:
            raise GcodeViewError(f"{name}: {exc.message}", field="name", value=exc.value) from None

    def _trace(self, session: Session, trace_id: str | None) -> Trace | None:
        return session.get(Trace, trace_id) if trace_id else None

    def _trace_of(self, session: Session, job: Job, depth: int = 0) -> Trace | None:
        trace = self._trace(session, job.params.get("trace_id"))
        if trace is not None or depth >= 4:
            return trace
        for key in ("plan_job_id", "probe_run_job_id", "reconstruct_job_id"):
            other = session.get(Job, job.params[key]) if job.params.get(key) else None
            if other is not None:
                return self._trace_of(session, other, depth + 1)
        return None

    # per kind ----------------------------------------------------------------------------
    def _content(self, session: Session, job: Job) -> FocusScene:
        loader = self._loaders().get(job.kind, self._generic)
        return loader(session, job)

    def _loaders(self) -> dict[str, Callable[[Session, Job], FocusScene]]:
        return {"probe_plan": self._probe_plan, "probe_run": self._probe_run, "reconstruct": self._reconstruct,
                "compensate": self._compensate, "closed_loop": self._closed_loop, "surface_fit": self._surface_fit,
                "five_axis": self._five_axis, "slice": self._slice, "jetting": self._jetting,
                "jetting_run": self._jetting_run, "print": lambda session, job: print_scene(self, session, job),
                **{kind: partial(build, self) for kind, build in PROGRAM_SCENES.items()}}

    def _with_trace(self, session: Session, job: Job, **parts: Any) -> FocusScene:
        trace = self._trace_of(session, job)
        lines = (Polyline(trace.name, nominal_of(trace).points),) if trace else ()
        return FocusScene({}, "", polylines=lines + tuple(parts.pop("polylines", ())), **parts)

    def _joint_ranges(self, session: Session, plan: Job | None) -> list[TraceRange] | None:
        """Each trace's range of the points of a joint probe plan (``trace_ids``); None otherwise."""
        ranges = joint_trace_ranges(plan) if plan is not None else None
        if ranges is None:
            return None
        out = []
        for trace_id, (first, stop) in ranges.items():
            trace = self._trace(session, trace_id)
            out.append(TraceRange(trace_id, trace, trace.name if trace else trace_id, first, stop))
        return out

    def _joint_scene(self, ranges: list[TraceRange], planned: np.ndarray,
                     measured: np.ndarray | None) -> FocusScene:
        """Every trace of a joint plan / run: its nominal and its own probes (and deviations)."""
        lines, probes, plots = [], [], []
        for _, trace, name, lo, hi in ranges:
            if trace is not None:
                lines.append(Polyline(name, nominal_of(trace).points))
            if measured is None:
                probes.append(ProbeSet(name, planned=planned[lo:hi]))
                continue
            probe, plot = self._measured_probes(trace, measured[lo:hi], name, planned=planned[lo:hi])
            probes.append(probe)
            plots.extend([plot] if plot else [])
        return FocusScene({}, "", polylines=tuple(lines), probes=tuple(probes), plots=tuple(plots))

    def _probe_plan(self, session: Session, job: Job) -> FocusScene:
        plan = ProbePlanResult.of(job)
        planned = np.asarray(plan.points, float).reshape(-1, 3)
        if plan.field:
            return self._field_plan(session, job, planned)
        ranges = self._joint_ranges(session, job)
        if ranges is not None:
            return self._joint_scene(ranges, planned, None)
        return self._with_trace(session, job, probes=(ProbeSet("plan", planned=planned),))

    def _field_plan(self, session: Session, job: Job, planned: np.ndarray) -> FocusScene:
        """A field plan: the traces, the stations and the field's posterior sd as a colour map
        on the part's top (the sd does not depend on what the probes will read)."""
        field = ProbePlanResult.of(job).field or {}
        stored = stored_field(field)
        trace_ids = job.params.get("trace_ids") or [job.params.get("trace_id")]
        lines = []
        for trace_id in trace_ids[:MAX_FIELD_POLYLINES]:
            trace = self._trace(session, trace_id)
            if trace is not None:
                lines.append(Polyline(trace.name, nominal_of(trace).points))
        notes = [f"{len(planned)} stations for {len(trace_ids)} traces; field degrees of freedom at the target "
                 f"{field['dof']:.0f}; largest sd on the traces "
                 f"{field['max_sd_mm'] * 1000:.2f} um"]
        if len(trace_ids) > MAX_FIELD_POLYLINES:
            notes.append(f"first {MAX_FIELD_POLYLINES} of {len(trace_ids)} traces drawn")
        part = self._part_of(session, job)
        maps: tuple[ScalarSurface, ...] = ()
        if part is not None and len(planned):
            vertices, faces, sd = field_sd_surface(self.runtime.meshes.mesh(part), stored.stations.take(~stored.verify),
                                                   stored.center, stored.prior, stored.prior.wavelength_mm / 4)
            if len(faces):
                maps = (ScalarSurface("posterior sd", vertices, faces, sd, 0.0, float(np.nanmax(sd))),)
                notes.append(f"colour: posterior sd 0 .. {float(np.nanmax(sd)) * 1000:.1f} um")
        return FocusScene({}, "", polylines=tuple(lines), probes=(ProbeSet("stations", planned=planned),),
                          scalar_surfaces=maps, notes=tuple(notes))

    def _measured_probes(self, trace: Trace | None, measured: np.ndarray, label: str,
                         planned: np.ndarray | None = None) -> tuple[ProbeSet, DeviationPlot | None]:
        if trace is None or not len(measured):
            return ProbeSet(label, planned=planned, measured=measured), None
        proj = project_onto_polyline(measured, nominal_of(trace).points)
        dz = measured[:, 2] - proj.nominal[:, 2]
        order = np.argsort(proj.s_mm)
        plot = DeviationPlot(trace.name, f"{trace.name}: measured - nominal (probes)", proj.s_mm[order], dz[order])
        return ProbeSet(label, planned=planned, measured=measured, deviation_mm=dz), plot

    def _probe_run(self, session: Session, job: Job) -> FocusScene:
        rows = ProbeRunResult.of(job).points
        nominal = np.asarray([r.nominal for r in rows], float).reshape(-1, 3)
        measured = np.asarray([r.measured for r in rows], float).reshape(-1, 3)
        ranges = self._joint_ranges(session, session.get(Job, job.params.get("plan_job_id", "")))
        if ranges is not None:
            return self._joint_scene(ranges, nominal, measured)
        probes, plot = self._measured_probes(self._trace_of(session, job), measured, "run", planned=nominal)
        return self._with_trace(session, job, probes=(probes,), plots=(plot,) if plot else ())

    def _board(self, session: Session, job: Job) -> FocusScene:
        """A board reconstruct / compensate job (``trace_ids``): each trace's nominal and
        rebuilt-deviation ribbon, and for compensate its compensated program (the first
        BOARD_DRAWN traces)."""
        rows = list(reconstruct_rows(job).items()) if job.kind == "reconstruct" else \
            list(compensate_rows(job).items())
        source = job if job.kind == "reconstruct" else session.get(Job, job.params.get("reconstruct_job_id") or "")
        samples_of = {t: r.deviation.samples for t, r in reconstruct_rows(source).items()} if source else {}
        lines: list[Polyline] = []
        ribbons: list[ScalarSurface] = []
        paths: list[Toolpath] = []
        for trace_id, row in rows[:BOARD_DRAWN]:
            trace = self._trace(session, trace_id)
            if trace is None:
                continue
            lines.append(Polyline(trace.name, nominal_of(trace).points))
            samples = np.asarray(samples_of.get(trace_id, []), float).reshape(-1, 2)
            ribbons.extend(_ribbon(trace, samples, f"{trace.name} {trace.id}"))
            if isinstance(row, CompensateResult):
                printed, _ = program_artifacts(row)
                paths.extend(self._gcode(session, job, printed, "compensated", f"{trace.name} compensated"))
        notes = (f"{len(rows) - BOARD_DRAWN} more traces not drawn",) if len(rows) > BOARD_DRAWN else ()
        return FocusScene({}, "", polylines=tuple(lines), toolpaths=tuple(paths), scalar_surfaces=tuple(ribbons),
                          notes=notes)

    def _reconstruct(self, session: Session, job: Job) -> FocusScene:
        if job.params.get("trace_ids"):
            return self._board(session, job)
        trace = self._trace_of(session, job)
        if job.params.get("points") is not None:
            measured = np.asarray(job.params["points"], float).reshape(-1, 3)
        else:
            run = session.get(Job, job.params.get("probe_run_job_id") or "")
            rows = ProbeRunResult.of(run).points if run else []
            plan = session.get(Job, run.params.get("plan_job_id", "")) if run else None
            own = (joint_trace_ranges(plan) or {}).get(job.params.get("trace_id", "")) if plan else None
            if own:  # a joint run: only this trace's own probes (the others are context)
                rows = [row for row in rows if own[0] <= row.index < own[1]]
            measured = np.asarray([r.measured for r in rows], float).reshape(-1, 3)
        probes, _ = self._measured_probes(trace, measured, "measured")
        result = ReconstructResult.of(job)
        curve = NurbsCurve.from_dict(result.curve)
        lo, hi = curve.domain
        rebuilt = Polyline(f"{trace.name if trace else 'trace'} reconstructed",
                           curve.evaluate(np.linspace(lo, hi, CURVE_SAMPLES)), role="reconstructed")
        samples = np.asarray(result.deviation.samples, float).reshape(-1, 2)
        name = trace.name if trace else job.id
        plot = DeviationPlot(name, f"{name}: reconstructed - nominal", samples[:, 0], samples[:, 1])
        return self._with_trace(session, job, polylines=(rebuilt,), probes=(probes,), plots=(plot,),
                                scalar_surfaces=_ribbon(trace, samples, name))

    def _gcode(self, session: Session, job: Job, name: str, role: str,
               label: str | None = None) -> tuple[Toolpath, ...]:
        segments = self._program(session, job, name)
        if segments is None:
            return ()
        return (Toolpath(label or name.rsplit(".", 1)[0], segments, role),)

    def _compensate(self, session: Session, job: Job) -> FocusScene:
        """Both programs, each dispensed move coloured by its standoff error over the rebuilt
        surface (the nominal program's is minus the deviation), and the deviation ribbon."""
        if job.params.get("trace_ids"):
            return self._board(session, job)
        paths = (self._gcode(session, job, "nominal.gcode", "nominal")
                 + self._gcode(session, job, "print.gcode", "compensated"))
        result = CompensateResult.of(job)
        offset = np.asarray(result.tool.get("offset_mm") or (0.0, 0.0, 0.0), float)
        if offset.any():  # a nozzle's programs are carriage positions: draw its tip (carriage + offset)
            paths = tuple(replace(p, segments=replace(p.segments, starts=p.segments.starts + offset,
                                                      ends=p.segments.ends + offset)) for p in paths)
        trace = self._trace_of(session, job)
        rebuilt = session.get(Job, job.params.get("reconstruct_job_id") or "")
        samples = np.asarray(ReconstructResult.of(rebuilt).deviation.samples if rebuilt else [], float).reshape(-1, 2)
        if trace is None or len(samples) < 2:
            return self._with_trace(session, job, toolpaths=paths)
        nominal = nominal_of(trace).points
        standoff = float(result.standoff_mm)
        colored = tuple(replace(p, standoff_error_mm=standoff_errors(
            p.segments.starts, p.segments.ends, p.segments.dispense, nominal, samples[:, 0], samples[:, 1], standoff))
            if len(p.segments.starts) <= MAX_COLORED_MOVES else p for p in paths)
        return self._with_trace(session, job, toolpaths=colored, scalar_surfaces=_ribbon(trace, samples, trace.name))

    def _closed_loop(self, session: Session, job: Job) -> FocusScene:
        children = session.exec(select(Job).where(Job.parent_id == job.id, Job.status == "succeeded")
                                .order_by(col(Job.created_at))).all()
        merged = FocusScene({}, "")
        for child in children:
            scene = self._content(session, child)
            # every child's nodes get its own name (its trace's, else its id): nine traces'
            # probe runs must not overwrite each other's "probe_run:run" node
            trace = self._trace(session, (child.params or {}).get("trace_id") or "")
            owner = f"{trace.name} {trace.id}" if trace is not None else child.id
            if child.kind == "compensate":  # its deviation ribbon is its reconstruct child's
                scene = replace(scene, scalar_surfaces=tuple(s for s in scene.scalar_surfaces if not s.signed))
            merged = replace(merged, **{key: getattr(merged, key) + tuple(
                replace(item, name=f"{child.kind}:{owner}:{item.name}") for item in getattr(scene, key))
                for key in ("polylines", "probes", "toolpaths", "layers", "axes", "heights", "surfaces", "plots",
                            "scalar_surfaces")})
        return self._loop_residuals(session, job, merged)

    def _loop_residuals(self, session: Session, job: Job, scene: FocusScene) -> FocusScene:
        """A field loop's verification residuals as a map on the part, and every trace its verdict
        names worse than nominal drawn again, highlighted (role "flagged")."""
        verdict = (job.result or {}).get("verdict")
        if not verdict:
            return scene
        trace_ids = list((job.params or {}).get("trace_ids") or [])
        found = {t: self._trace(session, t) for t in trace_ids}
        traces = {t: tr for t, tr in found.items() if tr is not None}
        nominals = {t: nominal_of(tr).points for t, tr in traces.items()}
        residuals = residual_map(verdict, trace_ids, nominals)
        flagged = tuple(Polyline(f"{traces[t].name} {t} worse than nominal", nominals[t], role="flagged")
                        for t in verdict.get("worse_traces") or [] if t in nominals)
        return replace(scene, polylines=scene.polylines + flagged,
                       residuals=scene.residuals + ((residuals,) if residuals is not None else ()))

    def _surface_fit(self, session: Session, job: Job) -> FocusScene:
        fit = SurfaceFitResult.of(job)
        mesh = NurbsSurface.from_dict(fit.surface).to_mesh(60, 60)
        grid = [p for p in fit.probe_grid.points if p[2] is not None]
        probes = (ProbeSet("probe grid", planned=np.asarray(grid, float).reshape(-1, 3)),) if grid else ()
        return FocusScene({}, "", probes=probes, surfaces=(
            SurfaceMesh("fitted surface", np.asarray(mesh.vertices), np.asarray(mesh.faces)),))

    def _five_axis(self, session: Session, job: Job) -> FocusScene:
        from app.five_axis.kinematics import (
            machine_to_workpiece,
            tool_axis_from_angles,
        )

        paths = list(self._gcode(session, job, "nominal.gcode", "nominal"))
        seg = self._program(session, job, "five_axis.gcode")
        axes: tuple[AxisGlyphs, ...] = ()
        if seg is not None:
            pivot = np.asarray(job.params.get("pivot") or [0.0, 0.0, 0.0], float)
            a, c = np.radians(seg.a_deg), np.radians(seg.c_deg)
            ends = machine_to_workpiece(seg.ends, a, c, pivot)
            starts = np.vstack([ends[:1], ends[:-1]])
            seg = replace(seg, starts=starts, ends=ends)
            paths.append(Toolpath("five_axis", seg, "compensated"))
            extent = float(np.ptp(ends, axis=0).max()) if len(ends) else 10.0
            axes = (AxisGlyphs("nozzle axis", ends[seg.dispense] if seg.dispense.any() else ends,
                               tool_axis_from_angles(a, c)[seg.dispense] if seg.dispense.any()
                               else tool_axis_from_angles(a, c), max(0.06 * extent, 0.5)),)
        return self._with_trace(session, job, toolpaths=tuple(paths), axes=axes)

    def _slice(self, session: Session, job: Job) -> FocusScene:
        data = self._artifact(session, job.id, "layers.json")
        if data is None:
            return FocusScene({}, "", notes=("slice job has no layers.json",))
        doc = json.loads(data)
        segments: list[np.ndarray] = []
        labels: list[str] = []
        for layer in doc.get("layers", []):
            z = float(layer.get("z_top", layer.get("z", 0.0)))
            rings = [r for isl in layer.get("islands", []) for r in [isl["outer"], *isl.get("holes", [])]]
            segments.append(rings_to_segments(rings, z))
            labels.append(f"layer {layer.get('index', len(labels))} z={z:.3f} mm")
        return FocusScene({}, "", layers=(LayerStack("slices", tuple(labels), tuple(segments)),))

    def _jetting(self, session: Session, job: Job) -> FocusScene:
        data = self._artifact(session, job.id, "heights.npz")
        if data is None:
            return FocusScene({}, "", notes=("jetting job has no heights.npz",))
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        key = "heights" if "heights" in arrays else next(
            (k for k, v in arrays.items() if v.ndim in (2, 3) and v.dtype.kind == "f"), None)
        if key is None:
            return FocusScene({}, "", notes=("heights.npz holds no height array",))
        heights = arrays[key] if arrays[key].ndim == 3 else arrays[key][None]
        layer_ids = next((arrays[k] for k in ("snapshot_layers", "layers") if k in arrays and arrays[k].ndim == 1),
                         None)
        labels = tuple(f"layer {int(i)}" for i in layer_ids) \
            if layer_ids is not None and len(layer_ids) == len(heights) \
            else tuple(f"snapshot {i}" for i in range(len(heights)))
        pitch = float(arrays["pitch_mm"]) if "pitch_mm" in arrays else 25.4 / float(job.params.get("dpi", 300))
        return FocusScene({}, "", heights=(HeightStack("heights", np.asarray(heights, float), pitch, labels),))

    def _jetting_run(self, session: Session, job: Job) -> FocusScene:
        """The measured maps (``measured_NNNN.npz``, as the controller used them), at most
        MAX_MEASURED_MAPS of them evenly over the layers measured so far, the last one always."""
        names = sorted(n for n in session.exec(select(Artifact.name).where(Artifact.job_id == job.id)).all()
                       if n.startswith("measured_") and n.endswith(".npz"))
        picked = [names[int(i)] for i in np.unique(np.linspace(0, len(names) - 1, MAX_MEASURED_MAPS).round())] \
            if names else []
        maps = []
        for name in picked:
            with np.load(io.BytesIO(self._artifact(session, job.id, name) or b""), allow_pickle=False) as npz:
                maps.append((np.asarray(npz["filled"], float), float(npz["pitch_mm"])))
        if not maps:
            return FocusScene({}, "", notes=("jetting_run job has measured no layer yet",))
        labels = tuple(f"layer {int(n[9:13])} (measured)" for n in picked)
        return FocusScene({}, "",
                          heights=(HeightStack("measured", np.stack([m for m, _ in maps]), maps[0][1], labels),))

    def _generic(self, session: Session, job: Job) -> FocusScene:
        rows = session.exec(select(Artifact).where(Artifact.job_id == job.id)).all()
        paths: tuple[Toolpath, ...] = ()
        for row in rows:
            if row.name.endswith(".gcode"):
                paths += self._gcode(session, job, row.name, "nominal")
        return self._with_trace(session, job, toolpaths=paths)


def _dispense_lines(job: Job) -> tuple[str | None, str | None]:
    """The program's dispense on/off lines as the job echoes them (result, else params)."""
    echo, params = ProgramEcho.of_any(job), job.params or {}
    return (echo.dispense_on or params.get("dispense_on"), echo.dispense_off or params.get("dispense_off"))


def load_focus(runtime: Any, part_id: str | None = None, job_id: str | None = None,
               parser: ParsePool | None = None) -> FocusScene:
    """The scene of a part or a job; NotFound names the missing id."""
    loader = Loader(runtime, parser)
    if job_id:
        return loader.job_scene(job_id)
    if part_id:
        return loader.part_scene(part_id)
    raise NotFound("give part_id or job_id", field="part_id", value=None)
