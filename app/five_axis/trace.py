"""Build a trace (3-D NURBS curve) lying on a surface (patent S3, steps 2-3).

* :func:`trace_on_surface` — through surface points at given (u, v) parameters;
* :func:`trace_over_xy` — a plan-view (x, y) polyline draped onto a surface that is a
  height field over the XY plane (each point solved for S(u, v)_xy = (x, y));
* :func:`plan_view_points` — a trace polyline's top view made fit for that: consecutive
  duplicates dropped, too short polylines subdivided.
The curve interpolates the surface points (cubic, chord length); between them it deviates
from the surface by the chordal sag of the sampling, which the planner reports.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from app.five_axis.errors import DegenerateTraceError, TraceOffSurfaceError
from app.geometry.fitting import interpolate_curve
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_surface import NurbsSurface
from app.geometry.tolerance import DEFAULT_TOLERANCE

__all__ = ["MIN_TRACE_POINTS", "plan_view_points", "trace_on_surface", "trace_over_xy", "uv_over_xy"]

MIN_TRACE_POINTS = 4  # a cubic trace curve interpolates at least degree + 1 points

_NEWTON_STEPS = 30
_SEED_GRID = 41
#: convergence (mm) of the plan-view inversion xy -> (u, v): Newton stops when every point's
#: xy residual is at or below this
_XY_INVERSION_TOL_MM = 1e-9
#: a point whose converged xy still misses by more than max(1e3 * tol_mm, this) mm is off the surface
_XY_MISS_FLOOR_MM = 1e-6


def plan_view_points(xy: npt.NDArray[np.float64], min_points: int = MIN_TRACE_POINTS,
                     dedup_mm: float = DEFAULT_TOLERANCE.dedup_mm) -> npt.NDArray[np.float64]:
    """Plan-view polyline xy (n, 2) mm -> (k, 2) mm points to interpolate, k >= min_points.

    A point within ``dedup_mm`` (mm, XY distance) of the point kept before it is dropped
    (the vertical steps of a draped polyline project onto one plan-view point).  While
    fewer than ``min_points`` points remain, the midpoint of the longest segment (the
    first one on ties) is inserted, so a straight polyline stays that straight line.
    Raises DegenerateTraceError (field ``trace.xy``) for xy that is not an (n, 2) array
    of finite numbers, or that has fewer than two points ``dedup_mm`` apart.
    """
    pts = np.asarray(xy, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
        raise DegenerateTraceError(f"plan-view points must be a finite (n, 2) array, got shape {pts.shape}",
                                   field="trace.xy", value=pts)
    if pts.shape[0] == 0:
        raise DegenerateTraceError("the trace has no plan-view points", field="trace.xy", value=pts)
    keep = [0]
    for i in range(1, pts.shape[0]):
        if float(np.linalg.norm(pts[i] - pts[keep[-1]])) > dedup_mm:
            keep.append(i)
    out: npt.NDArray[np.float64] = pts[keep]
    if out.shape[0] < 2:
        raise DegenerateTraceError(f"the trace's plan view is a single point (all {pts.shape[0]} points "
                                   f"within {dedup_mm} mm of the first)", field="trace.xy", value=pts[0])
    while out.shape[0] < min_points:
        longest = int(np.argmax(np.linalg.norm(np.diff(out, axis=0), axis=1)))
        out = np.insert(out, longest + 1, 0.5 * (out[longest] + out[longest + 1]), axis=0)
    return out


def trace_on_surface(surface: NurbsSurface, uv: npt.NDArray[np.float64], degree: int = 3) -> NurbsCurve:
    """Cubic interpolation of S(u_i, v_i) for uv (k,2) inside the domain -> NurbsCurve (mm)."""
    uv = np.asarray(uv, dtype=float)
    return interpolate_curve(surface.evaluate(uv[:, 0], uv[:, 1]), degree, field="trace.uv")


def uv_over_xy(surface: NurbsSurface, xy: npt.NDArray[np.float64],
               tol_mm: float = _XY_INVERSION_TOL_MM) -> npt.NDArray[np.float64]:
    """Surface parameters (k,2) whose points lie over the plan-view points xy (k,2) mm.

    Newton on S_xy(u, v) = (x, y) from the nearest of a 41 x 41 parameter sample.
    Raises TraceOffSurfaceError for a point outside the surface's XY footprint.
    """
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    (u0, u1), (v0, v1) = surface.domain
    gu, gv = np.meshgrid(np.linspace(u0, u1, _SEED_GRID), np.linspace(v0, v1, _SEED_GRID),
                         indexing="ij")
    seeds = np.column_stack([gu.ravel(), gv.ravel()])
    sample_xy = surface.evaluate(seeds[:, 0], seeds[:, 1])[:, :2]
    nearest = np.argmin(((xy[:, None, :] - sample_xy[None, :, :]) ** 2).sum(-1), axis=1)
    uv: npt.NDArray[np.float64] = seeds[nearest].copy()
    lo, hi = np.array([u0, v0]), np.array([u1, v1])
    for _ in range(_NEWTON_STEPS):
        d = surface.derivatives(uv[:, 0], uv[:, 1], 1)
        r = d[0][0][:, :2] - xy
        jac = np.stack([d[1][0][:, :2], d[0][1][:, :2]], axis=-1)  # (k, 2, 2)
        det = np.linalg.det(jac)
        safe = np.abs(det) > 1e-300
        step = np.zeros_like(uv)
        step[safe] = np.linalg.solve(jac[safe], r[safe][..., None])[..., 0]
        uv = np.clip(uv - step, lo, hi)
        if np.abs(r).max(initial=0.0) <= tol_mm:
            break
    miss = np.linalg.norm(surface.evaluate(uv[:, 0], uv[:, 1])[:, :2] - xy, axis=1)
    bad = np.flatnonzero(miss > max(1e3 * tol_mm, _XY_MISS_FLOOR_MM))
    if bad.size:
        j = int(bad[0])
        raise TraceOffSurfaceError(
            f"plan-view point {xy[j].round(4).tolist()} is outside the surface's footprint "
            f"(nearest surface point is {miss[j]:.4f} mm away in XY)",
            field="trace.xy", value={"index": j, "xy": xy[j], "miss_mm": miss[j]})
    return uv


def trace_over_xy(surface: NurbsSurface, xy: npt.NDArray[np.float64], degree: int = 3) -> NurbsCurve:
    """Drape a plan-view polyline xy (k,2) mm onto a height-field surface -> NurbsCurve."""
    return trace_on_surface(surface, uv_over_xy(surface, xy), degree)
