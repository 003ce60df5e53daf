"""Trace height compensation (the published method's step 5, job ``compensate``).

From a :class:`~app.reconstruction.reconstruct.Reconstruction` of the real trace, the
print path keeps the nozzle tip ``standoff_mm`` above the REAL surface:

    tip(s) = (x_nom(s), y_nom(s), h_real(s) + standoff)

for s along the nominal trace (arc length, mm).  The offset is along +Z: pneumatic
direct-write nozzles (the seed's conical nozzle) are mounted vertically and the standoff
is the vertical gap under the nozzle, so the designed top-view path is kept exactly and
only Z changes.  (An offset along the surface normal would move the tip off the designed
xy by standoff x slope and is not offered.)

Segmentation: the tip path is sampled densely (every ``verify_step_mm`` plus every
vertex of the nominal polyline), vertices are placed by the curvature of the compensated
curve, and every segment is *proved* within ``chord_error_mm``
(:mod:`app.compensation.print_path`).  The gap bound between adjacent samples comes from
the structure of the curve: between two nominal vertices the tip path is a straight line
plus the smooth deviation d(s) = tip_z - z_nom(s) in Z, so it leaves the chord of two
samples h apart by at most max|d''| h^2 / 8 (d'' from divided differences, times
``curvature_safety``).

Policy outside the probed span (the reconstruction's ``span_mm``: the first to the last
kept probe; a kriging model's reaches a quarter wavelength further): REFUSED
with :class:`OutsideProbedSpanError` (422, naming trace extent and probed extent) unless
the gap is within ``span_tolerance_mm`` or ``hold_mm`` allows it; then, and only then,
the deviation measured at the span's end is held constant over the gap (the tip follows
the nominal shape shifted by the end deviation) and the result says so
(``extension_mm``).  Nothing is extrapolated silently.

The *nominal* program beside it is the same trace at the same standoff above the CAD
surface: what the uncompensated machine would print.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Final

import numpy as np
from annotated_types import Ge, Gt, Le
from scipy.spatial import cKDTree

from app.compensation.print_path import SegmentedPath, dense_stations, segment_adaptive
from app.domain.checks import require_declared_bounds, require_non_negative, require_positive
from app.domain.errors import InvalidInput
from app.gcode.writer import DEFAULT_DIALECT, DIALECTS, ProgramBuilder
from app.geometry.slope import height_error_mm, surface_slopes_deg

__all__ = [
    "CompensatedPath",
    "CompensationError",
    "CompensationParams",
    "OutsideProbedSpanError",
    "compensate_trace",
    "real_surface_height",
    "tip_path",
]


class CompensationError(InvalidInput):
    """A reconstruction or setting that cannot give a safe print path (422)."""


class OutsideProbedSpanError(CompensationError):
    """The trace runs beyond the probed span by more than the policy allows."""


#: a trace's standoff when neither the job nor the trace (or circuit import) gives one, mm
DEFAULT_STANDOFF_MM: Final = 0.10


@dataclass(frozen=True)
class CompensationParams:
    """Compensation settings (mm, mm/min, s).

    standoff_mm: vertical nozzle-to-surface gap.  feed_mm_min: printing feed.
    chord_error_mm: largest distance between the emitted polyline and the compensated
        curve (proved per segment).  dispense_on / dispense_off: the machine profile's
        commands; None: the dialect's own (:func:`app.gcode.writer.own_dispense`, resolved
        here, so the fields read as text afterwards).  dialect: "marlin" | "grbl".
        clearance_mm: travel height above the highest of the path and ``part_max_z_mm``.
        approach_mm: the plunge starts this far above the first point and runs at
        ``plunge_feed_mm_min``.  dwell_s: pause after
        dispense_on (valve opening).  span_tolerance_mm: gap to the probed span that is
        accepted silently (probe xy placement noise).  hold_mm: largest gap over which the
        end deviation may be held (0: refuse).  max_deviation_mm: refuse a reconstruction
        that departs more than this from the nominal (wrong part, placement or probe).
        verify_step_mm: dense sampling step of the proof.  curvature_safety: factor on the
        estimated |d''| of the gap bound.  decimals: G-code coordinate decimals.
        xy_uncertainty_mm: lateral error of machine and placement assumed by the slope term
        of the error model (a vertical nozzle's standoff errs by xy x tan(slope)).
        tool: the nozzle (``T<tool>``, >= 1) the program selects first; None writes the
        probe-frame program of before (no tool line, carriage = tip).
        tool_offset_mm: (3,) that nozzle's offset o (tip = carriage + o); the programs are
        written in carriage coordinates, carriage = tip - o (points stay tips).
    The bounds in the annotations are the ranges a compensate job may ask for (its
    parameter model reads them); a value outside them is refused here too.
    """

    standoff_mm: float = DEFAULT_STANDOFF_MM
    feed_mm_min: Annotated[float, Gt(0), Le(100_000)] = 300.0
    chord_error_mm: Annotated[float, Gt(0), Le(1)] = 0.002
    dispense_on: str | None = None
    dispense_off: str | None = None
    dialect: str = DEFAULT_DIALECT
    clearance_mm: Annotated[float, Gt(0), Le(100)] = 2.0
    part_max_z_mm: float | None = None
    approach_mm: float = 0.5
    plunge_feed_mm_min: float = 60.0
    dwell_s: float = 0.0
    span_tolerance_mm: float = 0.005
    hold_mm: Annotated[float, Ge(0), Le(5)] = 0.0
    max_deviation_mm: float = 1.0
    verify_step_mm: float = 0.01
    curvature_safety: float = 2.0
    decimals: int = 4
    xy_uncertainty_mm: float = 0.01
    tool: int | None = None
    tool_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        positive = ("standoff_mm", "feed_mm_min", "chord_error_mm", "clearance_mm",
                    "approach_mm", "plunge_feed_mm_min", "max_deviation_mm", "verify_step_mm",
                    "curvature_safety")
        require_positive(self, positive, CompensationError)
        require_non_negative(self, ("dwell_s", "span_tolerance_mm", "hold_mm"),
                             CompensationError)
        require_declared_bounds(self, CompensationError)
        if self.part_max_z_mm is not None and not math.isfinite(self.part_max_z_mm):
            raise CompensationError("part_max_z_mm must be finite", field="part_max_z_mm",
                                    value=str(self.part_max_z_mm))
        if self.dialect not in DIALECTS:
            raise CompensationError(f"unknown dialect {self.dialect!r}; expected one of "
                                    f"{sorted(DIALECTS)}", field="dialect", value=self.dialect)
        for name, own in zip(("dispense_on", "dispense_off"), self._dialect_dispense(), strict=True):
            if getattr(self, name) is None:
                object.__setattr__(self, name, own)
            text = getattr(self, name)
            if not isinstance(text, str) or not text.strip() or "\n" in text or "\r" in text:
                raise CompensationError(f"{name} must be one non-empty G-code line",
                                        field=name, value=str(text)[:40])
        offset = np.asarray(self.tool_offset_mm, dtype=float)
        if offset.shape != (3,) or not np.isfinite(offset).all():
            raise CompensationError("tool_offset_mm must be three finite mm", field="tool_offset_mm",
                                    value=str(self.tool_offset_mm)[:60])
        if self.tool is None and np.any(offset != 0.0):
            raise CompensationError("a tool offset needs its tool", field="tool", value=None)
        if self.tool is not None and not (0 <= int(self.tool) <= 99):
            raise CompensationError("tool must be 0..99", field="tool", value=self.tool)
        if self.verify_step_mm > self.chord_error_mm * 50:
            raise CompensationError("verify_step_mm must be <= 50 x chord_error_mm",
                                    field="verify_step_mm", value=self.verify_step_mm)

    def _dialect_dispense(self) -> tuple[str | None, str | None]:
        """The dialect's own (on, off) dispenser commands, (None, None) when it has none
        (LinuxCNC: its outputs are numbered, so a profile or the request names them)."""
        rules = DIALECTS[self.dialect]
        return rules.dispense if rules.dispense is not None else (None, None)

    @property
    def dispense(self) -> tuple[str, str]:
        """The program's dispenser (on, off) commands (text once ``__post_init__`` resolved them)."""
        return str(self.dispense_on), str(self.dispense_off)


@dataclass(frozen=True, eq=False)
class CompensatedPath:
    """The compensated print path and its programs.

    points: (k, 3) nozzle-tip vertices, mm (machine frame of the reconstruction).
    s_mm: (k,) their arc length along the nominal trace.  program: compensated G-code.
    nominal_points: (j, 3) tip vertices at standoff above the CAD surface.
    nominal_program: the uncompensated G-code.  segments: printing G1 moves (k - 1).
    length_mm: 3-D length of the compensated polyline.  max_chord_error_mm: proved bound
    (<= chord_error_mm).  segment_error_mm: (k-1,) per-segment bound.
    span: (s0, s1) probed span.  trace_extent: (0, L).  extension_mm: (before, after)
    lengths over which the end deviation was held (0, 0 unless ``hold_mm`` allowed it).
    program_bounds / nominal_program_bounds: ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` mm
    the programs move to as written (what a reader of the text finds), None when the
    writer could not follow a line (a dispense command that moves).
    """

    points: np.ndarray
    s_mm: np.ndarray
    program: str
    nominal_points: np.ndarray
    nominal_program: str
    segments: int
    length_mm: float
    max_chord_error_mm: float
    segment_error_mm: np.ndarray
    span: tuple[float, float]
    trace_extent: tuple[float, float]
    extension_mm: tuple[float, float]
    standoff_mm: float
    dispense_on: str
    dispense_off: str
    method: str
    slope: dict[str, Any] | None = None
    program_bounds: list[list[float]] | None = None
    nominal_program_bounds: list[list[float]] | None = None

    def to_result(self) -> dict[str, Any]:
        """API result of job ``compensate``."""
        return {"dispense_on": self.dispense_on, "dispense_off": self.dispense_off,
                "segments": self.segments, "length_mm": self.length_mm,
                "max_chord_error_mm": self.max_chord_error_mm,
                "standoff_mm": self.standoff_mm, "method": self.method,
                "span_mm": list(self.span), "trace_extent_mm": list(self.trace_extent),
                "extension_mm": list(self.extension_mm),
                "nominal_segments": int(len(self.nominal_points) - 1),
                "slope": self.slope}


def slope_error_model(nominal: Any, s: np.ndarray, params: CompensationParams) -> dict[str, Any] | None:
    """The error model's slope term along the path: the surface slope (deg) from the nominal's
    normals and the standoff error ``xy_uncertainty_mm * tan(slope)`` it adds; None without
    normals."""
    normals = nominal.normals_at(s) if nominal.normals is not None else None
    if normals is None:
        return None
    slopes = surface_slopes_deg(normals)
    k = int(np.argmax(slopes))
    return {"max_slope_deg": round(float(slopes[k]), 4), "at_s_mm": round(float(s[k]), 4),
            "xy_uncertainty_mm": params.xy_uncertainty_mm,
            "max_height_error_mm": round(float(height_error_mm(slopes[k], params.xy_uncertainty_mm)), 6),
            "model": "standoff error = xy_uncertainty_mm x tan(surface slope) for a vertical nozzle, on top of "
                     "the reconstruction's error"}


def _span(reconstruction: Any, params: CompensationParams) -> tuple[float, float, float, float]:
    """(s0, s1) probed span and (before, after) gaps after applying the span policy."""
    length = float(reconstruction.nominal.length_mm)
    s0, s1 = (float(v) for v in reconstruction.span_mm)
    before, after = max(s0, 0.0), max(length - s1, 0.0)
    allowed = max(params.span_tolerance_mm, params.hold_mm)
    if before > allowed or after > allowed:
        raise OutsideProbedSpanError(
            f"trace extends over s = [0, {length:.3f}] mm but the probes cover only "
            f"[{s0:.3f}, {s1:.3f}] mm ({before:.3f} mm before, {after:.3f} mm after); "
            f"refusing to extrapolate beyond {allowed:.3f} mm (probe the trace ends, or set "
            f"hold_mm to hold the end deviation)", field="span",
            value={"trace_mm": [0.0, round(length, 4)], "probed_mm": [round(s0, 4), round(s1, 4)]})
    return s0, s1, before, after


def tip_path(reconstruction: Any, s: np.ndarray, standoff_mm: float,
             span: tuple[float, float]) -> np.ndarray:
    """Compensated tip points (m, 3) mm at stations ``s`` (m,) mm.

    Inside the probed ``span`` the reconstruction's real height is used; outside it the
    deviation at the nearer span end is held (callers decide whether that is allowed).
    """
    nominal = reconstruction.nominal
    s = np.asarray(s, dtype=float)
    pts = nominal.at(s)
    s0, s1 = span
    inside = (s >= s0) & (s <= s1)
    h = np.empty(len(s))
    if inside.any():
        h[inside] = reconstruction.height_at_s(s[inside])
    if (~inside).any():
        ends = np.array([s0, s1])
        dev_end = reconstruction.height_at_s(ends) - nominal.z_at(ends)
        out = s[~inside]
        h[~inside] = nominal.z_at(out) + np.where(out < s0, dev_end[0], dev_end[1])
    pts[:, 2] = h + standoff_mm
    placed: np.ndarray = pts
    return placed


def _gap_bound(s: np.ndarray, dev: np.ndarray, safety: float) -> np.ndarray:
    """Bound (N-1,) mm on the curve's departure from the line between adjacent samples:
    safety * max|d''| over the interval's ends * h^2 / 8 (d'' by divided differences)."""
    h = np.diff(s)
    slope = np.diff(dev) / h
    d2 = np.zeros(len(s))
    if len(s) > 2:
        d2[1:-1] = 2.0 * np.diff(slope) / (h[1:] + h[:-1])
        d2[0], d2[-1] = d2[1], d2[-2]
    worst = np.maximum(np.abs(d2[:-1]), np.abs(d2[1:]))
    out: np.ndarray = safety * worst * h ** 2 / 8.0
    return out


def _program(points: np.ndarray, params: CompensationParams, job_id: str | None,
             notes: list[str]) -> tuple[str, list[list[float]] | None]:
    """The program of tip ``points`` (k, 3) mm and its bounds as the writer wrote them
    (:meth:`app.gcode.writer.ProgramBuilder.bounds`); with a tool: ``T<tool>`` first and
    every coordinate in carriage terms (tip - offset)."""
    b = ProgramBuilder(params.dialect, "compensate", job_id, decimals=params.decimals)
    for note in notes:
        b.comment(note)
    top = float(points[:, 2].max())
    if params.part_max_z_mm is not None:
        top = max(top, float(params.part_max_z_mm))
    offset = np.asarray(params.tool_offset_mm, dtype=float)
    if params.tool is not None:
        b.comment(f"tool T{params.tool}: offset {offset.round(4).tolist()} mm, coordinates are the "
                  f"carriage = tip - offset")
        b.raw(f"T{int(params.tool)}")
    points = np.asarray(points, dtype=float) - offset
    travel_z = top + params.clearance_mm - offset[2]
    x0, y0, z0 = points[0]
    b.rapid(z=travel_z).rapid(x=x0, y=y0).rapid(z=z0 + params.approach_mm)
    b.move(z=z0, feed_mm_min=params.plunge_feed_mm_min)
    b.raw(params.dispense[0].strip())
    if params.dwell_s > 0:
        b.raw(b.dialect.dwell(params.dwell_s))
    b.extend_moves(points[1:], params.feed_mm_min)   # the feed on the first move only
    b.raw(params.dispense[1].strip())
    b.rapid(z=travel_z)
    b.end()
    return b.text(), b.bounds()


def _segment(reconstruction: Any, s: np.ndarray, pts: np.ndarray,
             params: CompensationParams) -> SegmentedPath:
    dev = pts[:, 2] - reconstruction.nominal.z_at(s)
    return segment_adaptive(s, pts, params.chord_error_mm,
                            _gap_bound(s, dev, params.curvature_safety))


def compensate_trace(reconstruction: Any, params: CompensationParams | None = None,
                     job_id: str | None = None) -> CompensatedPath:
    """Print path at ``params.standoff_mm`` above the reconstructed real surface.

    reconstruction: a Reconstruction (``.nominal`` TracePolyline, ``.span_mm`` the stretch its
    heights stand for, ``.height_at_s``, ``.method``).  Returns a :class:`CompensatedPath` with the
    compensated and nominal G-code.  Raises OutsideProbedSpanError when the trace leaves
    the probed span beyond the policy, CompensationError for a reconstruction departing
    more than ``max_deviation_mm`` from the nominal or with non-finite heights.
    """
    params = params or CompensationParams()
    nominal = reconstruction.nominal
    length = float(nominal.length_mm)
    s0, s1, before, after = _span(reconstruction, params)
    required = np.concatenate([nominal.s, [s0, s1]])
    s = dense_stations(0.0, length, params.verify_step_mm, required)
    pts = tip_path(reconstruction, s, params.standoff_mm, (s0, s1))
    dev = pts[:, 2] - params.standoff_mm - nominal.z_at(s)
    if not np.isfinite(dev).all():
        j = int(np.argmax(~np.isfinite(dev)))
        raise CompensationError(f"reconstructed height is not finite at s = {s[j]:.3f} mm",
                                field="reconstruction", value=float(s[j]))
    j = int(np.argmax(np.abs(dev)))
    if abs(dev[j]) > params.max_deviation_mm:
        raise CompensationError(
            f"the reconstructed surface departs {dev[j]:+.3f} mm from the nominal at "
            f"s = {s[j]:.3f} mm (limit {params.max_deviation_mm} mm): wrong part, placement "
            f"or a bad probe point; no program produced", field="reconstruction",
            value=round(float(dev[j]), 4))
    seg = _segment(reconstruction, s, pts, params)
    nominal_pts = nominal.at(s)
    nominal_pts[:, 2] += params.standoff_mm
    nominal_seg = segment_adaptive(s, nominal_pts, params.chord_error_mm, 0.0)
    method = str(getattr(reconstruction, "method", "unknown"))
    extension = (before if before > params.span_tolerance_mm else 0.0,
                 after if after > params.span_tolerance_mm else 0.0)
    notes = [(f"compensated trace: tip {params.standoff_mm:.4f} mm above the reconstructed "
              f"real surface [{method}], offset along +Z [vertical nozzle]"),
             (f"probed span s = {s0:.4f}..{s1:.4f} mm of 0..{length:.4f} mm; held end "
              f"deviation over {extension[0]:.4f} / {extension[1]:.4f} mm"),
             f"{len(seg.points) - 1} segments, proved chord error <= {seg.max_error_mm:.6f} mm"]
    nominal_notes = [(f"NOMINAL [uncompensated] trace: tip {params.standoff_mm:.4f} mm above "
                      f"the CAD surface"), f"{len(nominal_seg.points) - 1} segments"]
    program, bounds = _program(seg.points, params, job_id, notes)
    nominal_program, nominal_bounds = _program(nominal_seg.points, params, job_id, nominal_notes)
    return CompensatedPath(
        points=seg.points, s_mm=seg.s, program=program, program_bounds=bounds,
        nominal_points=nominal_seg.points, nominal_program=nominal_program, nominal_program_bounds=nominal_bounds,
        segments=int(len(seg.points) - 1),
        length_mm=float(np.linalg.norm(np.diff(seg.points, axis=0), axis=1).sum()),
        max_chord_error_mm=seg.max_error_mm, segment_error_mm=seg.segment_error_mm,
        span=(s0, s1), trace_extent=(0.0, length), extension_mm=extension,
        standoff_mm=float(params.standoff_mm), dispense_on=params.dispense[0].strip(),
        dispense_off=params.dispense[1].strip(), method=method,
        slope=slope_error_model(nominal, seg.s, params))


def real_surface_height(nominal_height: Callable[[np.ndarray], np.ndarray], reconstruction: Any,
                        span: tuple[float, float], floor_mm: float,
                        step_mm: float = 0.05) -> Callable[[np.ndarray], np.ndarray]:
    """The real surface near a trace: xy (k, 2) mm -> height (k,) mm.

    ``nominal_height`` is the placed nominal (CAD) top, NaN off the part; the real surface
    adds the reconstructed deviation d(s) = h_real(s) - z_nom(s) of the trace's station
    nearest in top view (stations every ``step_mm``; beyond the probed ``span`` the end
    deviation is held, as :func:`tip_path` does).  Off the part the height is
    ``floor_mm`` (e.g. the part's bottom: nothing higher to touch there).
    """
    nominal = reconstruction.nominal
    length = float(nominal.length_mm)
    s = np.linspace(0.0, length, max(2, int(np.ceil(length / step_mm)) + 1))
    deviation = tip_path(reconstruction, s, 0.0, span)[:, 2] - nominal.z_at(s)
    tree = cKDTree(nominal.at(s)[:, :2])

    def height(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        _, nearest = tree.query(xy)
        z = np.asarray(nominal_height(xy), dtype=float) + deviation[nearest]
        return np.where(np.isfinite(z), z, float(floor_mm))

    return height
