"""Plan a five-axis nozzle-normal traverse of a trace on a measured surface (the EHD patent's method).

``plan_five_axis(surface, trace, params)``:

1. interpolate the trace at constant feed with the second-order Taylor update at the servo
   period T (and, for comparison, the first-order update); measure both feed fluctuations;
2. keep every ``segment_mm / (v T)``-th servo sample as a program line; project those trace
   points, and the trace points halfway (in time) between them, onto the surface (contact
   points) and take the nozzle direction (surface normal, or the patent's principal normal);
3. choose A, C continuously over lines and midpoints together (:mod:`.branches`: no C
   flips, and a pole window around A = 0 where C is blended instead of following the
   normal's azimuth), round the lines' angles to the program's decimals and place the
   nozzle tip h above the contact point in machine coordinates;
4. midpoint check: the machine moves all five axes linearly between two lines, so a large
   rotary move swings the tip off the planned tip path (contact + h * planned nozzle axis);
   the tip halfway through each line is compared with the planned tip at that moment, and
   lines whose error exceeds ``midpoint_tol_mm`` are split at their midpoint (repeat);
5. verify independently: apply each line's (rounded) A and C to the surface normal
   (angle to +Z) and map the tip back to the workpiece to measure its distance to the
   surface (surface inversion);
6. write the five-axis program and the nominal three-axis program (nozzle h straight
   above each contact point, no tilt) with the same metrics for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.five_axis.branches import choose_axes
from app.five_axis.contact import ContactFrames, contact_frames
from app.five_axis.interpolation import (
    FeedFluctuation,
    feed_fluctuation,
    interpolate_parameters,
)
from app.five_axis.kinematics import (
    AxisPose,
    MachineConfig,
    machine_to_workpiece,
    rotation_matrices,
    tool_axis_from_angles,
    workpiece_to_machine,
)
from app.five_axis.params import FiveAxisParams
from app.five_axis.post import linuxcnc_trt_program
from app.five_axis.program import five_axis_program, nominal_program
from app.geometry.fitting import interpolate_curve
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_surface import NurbsSurface

__all__ = ["FiveAxisFigures", "FiveAxisPath", "plan_five_axis", "line_indices", "servo_times"]

_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class FiveAxisFigures:
    """A planned traverse's figures, as a job reports them (degrees, mm, s, percent or fraction).

    normal_source: "surface" or "principal"; lines: program lines (poses); servo_periods: number
    of servo periods; duration_s: total print time (s).
    max_normal_error_deg: max angle between +Z and the surface normal after A, C.
    max_standoff_error_mm: max | distance(tip, surface) - h | (surface inversion).
    max_midpoint_error_mm: max distance between the tip halfway (in time) through a linear
    move and the planned tip at that moment (contact + h * planned nozzle axis; the planned
    axis is the surface normal outside the pole window); at most ``midpoint_tol_mm``
    unless ``split_rounds`` reached ``max_split_rounds``.
    nominal_max_normal_error_deg / nominal_max_standoff_error_mm: same for the 3-axis program.
    feed_fluctuation_pct / feed_fluctuation_rms_pct: max and RMS relative feed error of the
    second-order interpolator (percent); ``*_first_order_*``: the same for the first-order one.
    max_c_step_deg / max_a_step_deg: largest rotary move between consecutive lines;
    max_c_speed_deg_s / max_a_speed_deg_s: largest rotary speed the program asks for.
    pole_lines: lines inside the pole window; split_lines: lines added by midpoint splits;
    split_rounds: halving rounds used.
    a_range_deg: [min, max] of the program's A angles (deg).
    max_trace_deviation_mm: max distance of the trace from the surface.
    feed_fluctuation / feed_fluctuation_first_order: the max relative feed errors again, as
    fractions.
    """

    normal_source: str
    lines: int
    servo_periods: int
    duration_s: float
    max_normal_error_deg: float
    max_standoff_error_mm: float
    max_midpoint_error_mm: float
    nominal_max_normal_error_deg: float
    nominal_max_standoff_error_mm: float
    feed_fluctuation_pct: float
    feed_fluctuation_rms_pct: float
    feed_fluctuation_first_order_pct: float
    feed_fluctuation_first_order_rms_pct: float
    max_c_step_deg: float
    max_a_step_deg: float
    max_c_speed_deg_s: float
    max_a_speed_deg_s: float
    pole_lines: int
    split_lines: int
    split_rounds: int
    a_range_deg: list[float]
    max_trace_deviation_mm: float
    feed_fluctuation: float
    feed_fluctuation_first_order: float


@dataclass(frozen=True)
class FiveAxisPath:
    """A planned five-axis traverse (k program poses).

    program / nominal_program: G-code text (five-axis, and three-axis for comparison).
    axes: machine poses (xyz_mm (k,3), a_rad, c_rad (k,)) as written (angles rounded).
    u: (k,) trace parameters of the poses; frames: their contact data.
    durations_s: (k-1,) segment times at the set feed.
    offset_curve: f(u), a NURBS curve through the nozzle tips (workpiece coordinates).
    feed: second-order feed fluctuation; feed_first_order: the first-order one.
    figures: the traverse's figures (:class:`FiveAxisFigures`: errors, rotary moves, time).
    """

    program: str
    nominal_program: str
    axes: AxisPose
    u: npt.NDArray[np.float64]
    frames: ContactFrames
    durations_s: npt.NDArray[np.float64]
    offset_curve: NurbsCurve
    feed: FeedFluctuation
    feed_first_order: FeedFluctuation
    figures: FiveAxisFigures


def line_indices(n_samples: int, stride: int) -> npt.NDArray[np.int64]:
    """Indices of the servo samples written as lines: every stride-th, plus the last."""
    idx = np.arange(0, n_samples, max(1, stride), dtype=np.int64)
    return idx if idx[-1] == n_samples - 1 else np.append(idx, n_samples - 1)


def servo_times(n_samples: int, period_s: float, last_fraction: float) -> npt.NDArray[np.float64]:
    """Time (s) at each of n servo samples: whole periods, the final one partial."""
    per = np.full(n_samples - 1, period_s)
    per[-1] = period_s * last_fraction
    return np.concatenate([[0.0], np.cumsum(per)])


def _angle_to_z_deg(directions: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(k,) angle (deg) between each direction (k, 3) and +Z."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    angle: npt.NDArray[np.float64] = np.degrees(np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2]))
    return angle


def _take(frames: ContactFrames, idx: npt.NDArray[np.int64]) -> ContactFrames:
    """The frames at indices ``idx``."""
    return ContactFrames(u=frames.u[idx], trace_points=frames.trace_points[idx],
                         contact=frames.contact[idx], uv=frames.uv[idx],
                         surface_normal=frames.surface_normal[idx],
                         direction=frames.direction[idx],
                         trace_deviation_mm=frames.trace_deviation_mm[idx],
                         normal_source=frames.normal_source)


@dataclass(frozen=True)
class _Poses:
    """Program poses of k lines planned together with their k-1 time midpoints."""

    frames: ContactFrames  # the lines'
    axes: AxisPose  # the lines' (angles rounded as written)
    a_deg: npt.NDArray[np.float64]
    c_deg: npt.NDArray[np.float64]
    pole: npt.NDArray[np.bool_]  # (k,) lines in the pole window
    times_s: npt.NDArray[np.float64]  # (k,)
    mid_u: npt.NDArray[np.float64]  # (k-1,)
    midpoint_error_mm: npt.NDArray[np.float64]  # (k-1,)


def _plan_poses(surface: NurbsSurface, trace: NurbsCurve, u_lines: npt.NDArray[np.float64],
                params: FiveAxisParams, machine: MachineConfig, servo_u: npt.NDArray[np.float64],
                servo_t: npt.NDArray[np.float64]) -> _Poses:
    """Axes for lines at trace parameters u_lines (k,), and their midpoint tip errors."""
    h = params.standoff_mm
    t_lines = np.interp(u_lines, servo_u, servo_t)
    mid_u = np.interp(0.5 * (t_lines[1:] + t_lines[:-1]), servo_t, servo_u)
    k = u_lines.size
    u_all = np.empty(2 * k - 1)
    u_all[0::2], u_all[1::2] = u_lines, mid_u
    frames = contact_frames(surface, trace, u_all, on_surface_tol_mm=params.on_surface_tol_mm,
                            normal_source=params.normal, normal_side=params.normal_side)
    choice = choose_axes(frames.direction, machine, c_start_rad=np.radians(params.c_start_deg),
                         pole_tilt_rad=np.radians(params.pole_window_deg),
                         arc_mm=params.feed_mm_s * np.interp(u_all, servo_u, servo_t))
    a_deg: npt.NDArray[np.float64] = np.degrees(choice.a_rad[0::2]).round(params.decimals)
    c_deg: npt.NDArray[np.float64] = np.degrees(choice.c_rad[0::2]).round(params.decimals)
    a, c = np.radians(a_deg), np.radians(c_deg)
    pivot = machine.pivot
    xyz = workpiece_to_machine(frames.contact[0::2], a, c, pivot) + h * _Z
    planned_mid = frames.contact[1::2] + h * tool_axis_from_angles(choice.a_rad[1::2],
                                                                    choice.c_rad[1::2])
    moved_mid = machine_to_workpiece(0.5 * (xyz[1:] + xyz[:-1]), 0.5 * (a[1:] + a[:-1]),
                                     0.5 * (c[1:] + c[:-1]), pivot)
    return _Poses(frames=_take(frames, np.arange(0, 2 * k - 1, 2, dtype=np.int64)),
                  axes=AxisPose(xyz_mm=xyz, a_rad=a, c_rad=c), a_deg=a_deg, c_deg=c_deg,
                  pole=choice.held[0::2], times_s=t_lines, mid_u=mid_u,
                  midpoint_error_mm=np.linalg.norm(moved_mid - planned_mid, axis=1))


def _max_speed(step_deg: npt.NDArray[np.float64], durations_s: npt.NDArray[np.float64]) -> float:
    ok = durations_s > 0
    return float((np.abs(step_deg[ok]) / durations_s[ok]).max(initial=0.0))


def plan_five_axis(surface: NurbsSurface, trace: NurbsCurve,
                   params: FiveAxisParams) -> FiveAxisPath:
    """Plan the traverse of ``trace`` (3-D NURBS curve on ``surface``), see module doc.

    Raises TraceOffSurfaceError (trace leaves the surface), AxisLimitError (a normal
    needs A beyond the limits), DegenerateTraceError (zero-length trace, or a straight
    trace with the principal normal), FiveAxisError (bad parameters).
    """
    h = params.standoff_mm
    machine = params.machine()
    sched = interpolate_parameters(trace, params.feed_mm_s, params.period_s, order=2)
    sched1 = interpolate_parameters(trace, params.feed_mm_s, params.period_s, order=1)
    fluct2, fluct1 = feed_fluctuation(trace, sched), feed_fluctuation(trace, sched1)
    n = sched.u.size
    servo_t = servo_times(n, params.period_s, fluct2.last_step_mm / sched.step_mm)
    stride = int(round(params.segment_mm / sched.step_mm))
    u_lines = sched.u[line_indices(n, stride)]
    first_count = u_lines.size
    rounds = 0
    while True:
        poses = _plan_poses(surface, trace, u_lines, params, machine, sched.u, servo_t)
        split = poses.midpoint_error_mm > params.midpoint_tol_mm
        if not split.any() or rounds >= params.max_split_rounds:
            break
        u_lines = np.sort(np.concatenate([u_lines, poses.mid_u[split]]))
        rounds += 1
    frames, axes, a_deg, c_deg = poses.frames, poses.axes, poses.a_deg, poses.c_deg
    xyz, a, c, pivot = axes.xyz_mm, axes.a_rad, axes.c_rad, machine.pivot
    durations = np.diff(poses.times_s)

    # independent verification of what the program does
    turned = np.einsum("kij,kj->ki", rotation_matrices(a, c), frames.surface_normal)
    normal_err = _angle_to_z_deg(turned)
    tip_wp = machine_to_workpiece(xyz, a, c, pivot)
    standoff_err = np.abs(surface.invert(tip_wp).distance - h)
    nominal_xyz = frames.contact + h * _Z
    nominal_standoff_err = np.abs(surface.invert(nominal_xyz).distance - h)

    frame = "workpiece" if params.post == "linuxcnc_xyzac_trt" else "machine"
    feed_words = ("[G93, F = 1/minutes per line]" if params.feed_mode == "inverse_time"
                  else f"[G94, F = tip mm/min in {frame} coordinates]")
    header = [
        (f"five-axis table-tilting A[about X]/C[about Z], pivot {list(machine.pivot_mm)} mm,"
         " X Y Z = nozzle tip in machine coordinates"),
        (f"nozzle direction: {frames.normal_source} normal, standoff {h} mm; within "
         f"{params.pole_window_deg} deg of A = 0 C is blended [pole window]"),
        f"feed mode: {params.feed_mode} {feed_words}, trace feed {params.feed_mm_min} mm/min",
        f"servo period {params.period_s} s, second-order Taylor parameter update",
    ]
    if params.post == "linuxcnc_xyzac_trt":
        program = linuxcnc_trt_program(tip_wp, a_deg, c_deg, durations, params.feed_mode,
                                       params.feed_mm_min, params.style(), header[1:],
                                       machine.pivot_mm)
    else:
        program = five_axis_program(xyz, a_deg, c_deg, durations, params.feed_mode,
                                    params.feed_mm_min, params.style(), header)
    nominal = nominal_program(nominal_xyz, params.feed_mm_min, params.style(),
                              [(f"nominal three-axis traverse, nozzle {h} mm straight above "
                                "the contact points, no tilt")])
    offset_curve = interpolate_curve(frames.contact + h * frames.direction, 3,
                                     field="trace")
    c_step, a_step = np.diff(c_deg), np.diff(a_deg)
    figures = FiveAxisFigures(
        normal_source=frames.normal_source, lines=int(frames.u.size), servo_periods=int(n - 1),
        duration_s=float(durations.sum()),
        max_normal_error_deg=float(normal_err.max()),
        max_standoff_error_mm=float(standoff_err.max()),
        max_midpoint_error_mm=float(poses.midpoint_error_mm.max(initial=0.0)),
        nominal_max_normal_error_deg=float(_angle_to_z_deg(frames.surface_normal).max()),
        nominal_max_standoff_error_mm=float(nominal_standoff_err.max()),
        feed_fluctuation_pct=100.0 * fluct2.max_rel, feed_fluctuation_rms_pct=100.0 * fluct2.rms_rel,
        feed_fluctuation_first_order_pct=100.0 * fluct1.max_rel,
        feed_fluctuation_first_order_rms_pct=100.0 * fluct1.rms_rel,
        max_c_step_deg=float(np.abs(c_step).max(initial=0.0)),
        max_a_step_deg=float(np.abs(a_step).max(initial=0.0)),
        max_c_speed_deg_s=_max_speed(c_step, durations),
        max_a_speed_deg_s=_max_speed(a_step, durations),
        pole_lines=int(poses.pole.sum()), split_lines=int(u_lines.size - first_count),
        split_rounds=rounds, a_range_deg=[float(np.degrees(a.min())), float(np.degrees(a.max()))],
        max_trace_deviation_mm=float(frames.trace_deviation_mm.max()),
        feed_fluctuation=fluct2.max_rel, feed_fluctuation_first_order=fluct1.max_rel)
    return FiveAxisPath(
        program=program, nominal_program=nominal, axes=axes, u=frames.u, frames=frames,
        durations_s=durations, offset_curve=offset_curve, feed=fluct2, feed_first_order=fluct1,
        figures=figures)
