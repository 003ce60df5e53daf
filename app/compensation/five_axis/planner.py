"""Plan a five-axis nozzle-normal traverse of a trace on a measured surface (seed S3).

``plan_five_axis(surface, trace, params)``:

1. interpolate the trace at constant feed with the second-order Taylor update at the servo
   period T (and, for comparison, the first-order update); measure both feed fluctuations;
2. keep every ``segment_mm / (v T)``-th servo sample as a program line; project those trace
   points onto the surface (contact points) and take the nozzle direction (surface normal,
   or the patent's principal normal);
3. choose A, C continuously (:mod:`.branches`), round them to the program's decimals and
   place the nozzle tip h above the contact point in machine coordinates;
4. verify independently: apply each line's (rounded) A and C to the surface normal
   (angle to +Z) and map the tip back to the workpiece to measure its distance to the
   surface (surface inversion); check the midpoint of each linear segment too;
5. write the five-axis program and the nominal three-axis program (nozzle h straight
   above each contact point, no tilt) with the same metrics for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from app.compensation.five_axis.branches import choose_axes
from app.compensation.five_axis.contact import ContactFrames, contact_frames
from app.compensation.five_axis.interpolation import (
    FeedFluctuation,
    feed_fluctuation,
    interpolate_parameters,
)
from app.compensation.five_axis.kinematics import (
    AxisPose,
    machine_to_workpiece,
    rotation_matrices,
    workpiece_to_machine,
)
from app.compensation.five_axis.params import FiveAxisParams
from app.compensation.five_axis.program import five_axis_program, nominal_program
from app.geometry.fitting import interpolate_curve
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_surface import NurbsSurface

__all__ = ["FiveAxisPath", "plan_five_axis", "line_indices", "segment_durations"]

_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class FiveAxisPath:
    """A planned five-axis traverse (k program poses).

    program / nominal_program: G-code text (five-axis, and three-axis for comparison).
    axes: machine poses (xyz_mm (k,3), a_rad, c_rad (k,)) as written (angles rounded).
    u: (k,) trace parameters of the poses; frames: their contact data.
    durations_s: (k-1,) segment times at the set feed.
    offset_curve: f(u), a NURBS curve through the nozzle tips (workpiece coordinates).
    normal_source: "surface" or "principal".
    max_normal_error_deg: max angle between +Z and the surface normal after A, C.
    max_standoff_error_mm: max | distance(tip, surface) - h | (surface inversion).
    max_midpoint_error_mm: max distance between the tip of a linear move's midpoint and the
    ideal tip at the trace's mid parameter (the chordal error of the program).
    nominal_max_normal_error_deg / nominal_max_standoff_error_mm: same for the 3-axis program.
    feed: second-order feed fluctuation; feed_first_order: the first-order one.
    max_c_step_deg / max_a_step_deg: largest rotary move between consecutive lines.
    max_trace_deviation_mm: max distance of the trace from the surface.
    servo_periods: number of servo periods; duration_s: total print time.
    """

    program: str
    nominal_program: str
    axes: AxisPose
    u: np.ndarray
    frames: ContactFrames
    durations_s: np.ndarray
    offset_curve: NurbsCurve
    normal_source: str
    max_normal_error_deg: float
    max_standoff_error_mm: float
    max_midpoint_error_mm: float
    nominal_max_normal_error_deg: float
    nominal_max_standoff_error_mm: float
    feed: FeedFluctuation
    feed_first_order: FeedFluctuation
    max_c_step_deg: float
    max_a_step_deg: float
    max_trace_deviation_mm: float
    servo_periods: int
    duration_s: float

    @property
    def feed_fluctuation(self) -> float:
        """Max relative feed error of the second-order interpolator."""
        return self.feed.max_rel

    def summary(self) -> dict[str, Any]:
        """JSON-friendly metrics (degrees, mm, percent) for a job result."""
        return {
            "normal_source": self.normal_source,
            "lines": int(self.u.size),
            "servo_periods": self.servo_periods,
            "duration_s": self.duration_s,
            "max_normal_error_deg": self.max_normal_error_deg,
            "max_standoff_error_mm": self.max_standoff_error_mm,
            "max_midpoint_error_mm": self.max_midpoint_error_mm,
            "nominal_max_normal_error_deg": self.nominal_max_normal_error_deg,
            "nominal_max_standoff_error_mm": self.nominal_max_standoff_error_mm,
            "feed_fluctuation_pct": 100.0 * self.feed.max_rel,
            "feed_fluctuation_rms_pct": 100.0 * self.feed.rms_rel,
            "feed_fluctuation_first_order_pct": 100.0 * self.feed_first_order.max_rel,
            "feed_fluctuation_first_order_rms_pct": 100.0 * self.feed_first_order.rms_rel,
            "max_c_step_deg": self.max_c_step_deg,
            "max_a_step_deg": self.max_a_step_deg,
            "a_range_deg": [float(np.degrees(self.axes.a_rad.min())),
                            float(np.degrees(self.axes.a_rad.max()))],
            "max_trace_deviation_mm": self.max_trace_deviation_mm,
        }


def line_indices(n_samples: int, stride: int) -> np.ndarray:
    """Indices of the servo samples written as lines: every stride-th, plus the last."""
    idx = np.arange(0, n_samples, max(1, stride))
    return idx if idx[-1] == n_samples - 1 else np.append(idx, n_samples - 1)


def segment_durations(idx: np.ndarray, n_samples: int, period_s: float,
                      last_fraction: float) -> np.ndarray:
    """Time of each line segment (k-1,) s: whole periods, the final one partial."""
    per = np.full(n_samples - 1, period_s)
    per[-1] = period_s * last_fraction
    cum = np.concatenate([[0.0], np.cumsum(per)])
    return np.diff(cum[idx])


def _angle_to_z_deg(directions: np.ndarray) -> np.ndarray:
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return np.degrees(np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2]))


def plan_five_axis(surface: NurbsSurface, trace: NurbsCurve,
                   params: FiveAxisParams) -> FiveAxisPath:
    """Plan the traverse of ``trace`` (3-D NURBS curve on ``surface``), see module doc.

    Raises TraceOffSurfaceError (trace leaves the surface), AxisLimitError (a normal
    needs A beyond the limits), DegenerateTraceError (zero-length trace, or a straight
    trace with the principal normal), FiveAxisError (bad parameters).
    """
    h = params.standoff_mm
    machine = params.machine()
    sched = interpolate_parameters(trace, params.feed_mm_s, params.servo_period_s, order=2)
    sched1 = interpolate_parameters(trace, params.feed_mm_s, params.servo_period_s, order=1)
    fluct2, fluct1 = feed_fluctuation(trace, sched), feed_fluctuation(trace, sched1)
    n = sched.u.size
    stride = int(round(params.segment_mm / sched.step_mm))
    idx = line_indices(n, stride)
    durations = segment_durations(idx, n, params.servo_period_s,
                                  fluct2.last_step_mm / sched.step_mm)
    frames = contact_frames(surface, trace, sched.u[idx],
                            on_surface_tol_mm=params.on_surface_tol_mm,
                            normal_source=params.normal_source, normal_side=params.normal_side)
    choice = choose_axes(frames.direction, machine, c_start_rad=np.radians(params.c_start_deg),
                         singular_rho=np.sin(np.radians(params.singular_tilt_deg)))
    a_deg = np.round(np.degrees(choice.a_rad), params.decimals)
    c_deg = np.round(np.degrees(choice.c_rad), params.decimals)
    a, c = np.radians(a_deg), np.radians(c_deg)
    pivot = machine.pivot
    xyz = workpiece_to_machine(frames.contact, a, c, pivot) + h * _Z
    axes = AxisPose(xyz_mm=xyz, a_rad=a, c_rad=c)

    # independent verification of what the program does
    turned = np.einsum("kij,kj->ki", rotation_matrices(a, c), frames.surface_normal)
    normal_err = _angle_to_z_deg(turned)
    tip_wp = machine_to_workpiece(xyz, a, c, pivot)
    standoff_err = np.abs(surface.invert(tip_wp).distance - h)
    mid_u = 0.5 * (frames.u[1:] + frames.u[:-1])
    mid_frames = contact_frames(surface, trace, mid_u, on_surface_tol_mm=params.on_surface_tol_mm,
                                normal_source=params.normal_source,
                                normal_side=params.normal_side)
    ideal_mid = mid_frames.contact + h * mid_frames.direction
    am, cm = 0.5 * (a[1:] + a[:-1]), 0.5 * (c[1:] + c[:-1])
    mid_tip = machine_to_workpiece(0.5 * (xyz[1:] + xyz[:-1]), am, cm, pivot)
    midpoint_err = np.linalg.norm(mid_tip - ideal_mid, axis=1)
    nominal_xyz = frames.contact + h * _Z
    nominal_standoff_err = np.abs(surface.invert(nominal_xyz).distance - h)

    header = [
        f"five-axis table-tilting A[about X]/C[about Z], pivot {list(machine.pivot_mm)} mm,"
        " X Y Z = nozzle tip in machine coordinates",
        f"nozzle direction: {frames.normal_source} normal, standoff {h} mm",
        f"feed mode: {params.feed_mode} "
        + ("[G93, F = 1/minutes per line]" if params.feed_mode == "inverse_time"
           else "[G94, F = tip mm/min in machine coordinates]")
        + f", trace feed {params.feed_mm_min} mm/min",
        f"servo period {params.servo_period_s} s, second-order Taylor parameter update",
    ]
    program = five_axis_program(xyz, a_deg, c_deg, durations, params.feed_mode,
                                params.feed_mm_min, params.style(), header)
    nominal = nominal_program(nominal_xyz, params.feed_mm_min, params.style(),
                              [f"nominal three-axis traverse, nozzle {h} mm straight above "
                               "the contact points, no tilt"])
    offset_curve = interpolate_curve(frames.contact + h * frames.direction, 3,
                                     field="trace")
    return FiveAxisPath(
        program=program, nominal_program=nominal, axes=axes, u=frames.u, frames=frames,
        durations_s=durations, offset_curve=offset_curve, normal_source=frames.normal_source,
        max_normal_error_deg=float(normal_err.max()),
        max_standoff_error_mm=float(standoff_err.max()),
        max_midpoint_error_mm=float(midpoint_err.max(initial=0.0)),
        nominal_max_normal_error_deg=float(_angle_to_z_deg(frames.surface_normal).max()),
        nominal_max_standoff_error_mm=float(nominal_standoff_err.max()),
        feed=fluct2, feed_first_order=fluct1,
        max_c_step_deg=float(np.abs(np.diff(c_deg)).max(initial=0.0)),
        max_a_step_deg=float(np.abs(np.diff(a_deg)).max(initial=0.0)),
        max_trace_deviation_mm=float(frames.trace_deviation_mm.max()),
        servo_periods=int(n - 1), duration_s=float(durations.sum()))
