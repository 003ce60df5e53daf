"""The trace polyline, the one shape of a nominal trace, and how the service creates it.

:class:`TracePolyline` is a dense 3-D polyline on the part: points (k, 3) mm, cumulative
3-D arc length ``s`` (k,) mm, optional unit normals (k, 3), and the two summaries stored
with a trace (``slope_stretch``, the ``slope`` report).  Probing, reconstruction,
compensation and registration take it as the truth of the CAD model along the trace: for
a trace draped onto a faceted mesh it holds every triangle-edge crossing, so linear
interpolation between its points is exact for that mesh.  :meth:`TracePolyline.to_dict` /
:meth:`TracePolyline.from_dict` are the stored JSON (``Trace.nominal``):
``{"points": [[x, y, z], ...], "normals": [...], "slope_stretch": f, "slope": {...}}``,
coordinates rounded to 1e-6 mm (:data:`~app.geometry.tolerance.STORED_DECIMALS`).

:func:`build_nominal_trace` (geometry dict -> trace polyline on the part): frame "xy": the
design curve is drawn in the part's top view; it becomes a top-view polyline within
``tolerance.chord_mm`` (verified CL points) and is draped exactly onto the mesh's upper
surface.  frame "3d": the curve lies on the surface; its CL points are snapped to the mesh
and any point farther than ``tolerance.snap_mm`` is an error naming it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np
import trimesh

from app.geometry.cl_points import cl_points, cl_points_many
from app.geometry.drape import drape_polyline, snap_to_surface
from app.geometry.drape_batch import drape_polylines
from app.geometry.errors import DegenerateGeometryError, GeometryError
from app.geometry.shapes import trace_curve
from app.geometry.shapes_limits import curves_clearly_within_limits
from app.geometry.tolerance import DEFAULT_TOLERANCE, LENGTH_EPS_MM, STORED_DECIMALS, Tolerance

__all__ = ["TracePolyline", "TracePolylineError", "XYProjection", "as_trace_polyline", "build_nominal_trace",
           "build_nominal_traces"]

Frame = Literal["xy", "3d"]


class TracePolylineError(DegenerateGeometryError):
    """A trace polyline that cannot be used (too few points, non-finite, zero length): 422."""


class XYProjection(NamedTuple):
    """Closest points on the polyline's top view: ``s`` (m,) mm, ``distance_mm`` (m,)."""

    s: np.ndarray
    distance_mm: np.ndarray


def _rounded(rows: np.ndarray) -> list[list[float]]:
    """``rows`` (k, d) as lists of ``round(v, STORED_DECIMALS)``, exactly Python's values,
    vectorised: the nearest integer of v * 10**n divided by 10**n is the double nearest that
    decimal, as Python's round gives it; near a tie (where v * 10**n is inexact enough to
    pick the other integer), beyond 2**52 or not finite, Python's round is taken."""
    arr = np.asarray(rows, dtype=float)
    scale = 10.0 ** STORED_DECIMALS
    with np.errstate(invalid="ignore", over="ignore"):
        scaled = arr * scale
        out: list[list[float]] = (np.rint(scaled) / scale).tolist()
        unsure = ~(np.abs(scaled) < 2.0 ** 52) | (np.abs(scaled - np.floor(scaled) - 0.5) < 1e-6)
    for i, j in zip(*np.nonzero(unsure)):
        out[i][j] = round(float(arr[i, j]), STORED_DECIMALS)
    return out


@dataclass(frozen=True, eq=False)
class TracePolyline:
    """Dense nominal polyline of a trace.

    points: (k, 3) mm, consecutive duplicates removed (by :meth:`from_points`).
    s: (k,) cumulative 3-D arc length, mm, s[0] = 0.
    normals: (k, 3) unit surface normals (upward) or None.
    slope_stretch: 3-D length / top-view length, or None (not known).
    slope: the stored slope summary (:meth:`app.geometry.slope.SlopeReport.to_json`) or None.
    """

    points: np.ndarray
    s: np.ndarray
    normals: np.ndarray | None = None
    slope_stretch: float | None = None
    slope: dict[str, Any] | None = None

    # construction -------------------------------------------------------------------------
    @classmethod
    def from_points(cls, points: Any, normals: Any = None, *, field: str = "nominal",
                    slope_stretch: float | None = None, slope: dict[str, Any] | None = None) -> TracePolyline:
        """Validate ``points`` (k >= 2, 3) mm, drop consecutive duplicates (closer than
        :data:`~app.geometry.tolerance.LENGTH_EPS_MM`) and measure ``s``.

        ``normals`` (k, 3) are kept (renormalised) when finite and of the points' shape, else
        dropped.  Raises :class:`TracePolylineError` naming ``field``."""
        try:
            pts = np.asarray(points, dtype=float)
        except (TypeError, ValueError) as exc:
            raise TracePolylineError(f"{field}.points must be numeric", field=f"{field}.points",
                                     value=str(points)[:60]) from exc
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise TracePolylineError(f"{field}.points must be (k >= 2, 3)", field=f"{field}.points",
                                     value=list(pts.shape))
        if not np.isfinite(pts).all():
            i = int(np.argmax(~np.isfinite(pts).all(axis=1)))
            raise TracePolylineError(f"{field}.points[{i}] is not finite",
                                     field=f"{field}.points[{i}]", value=str(pts[i].tolist()))
        step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        keep = np.concatenate([[True], step > LENGTH_EPS_MM])
        unit = None
        if normals is not None:
            n = np.asarray(normals, dtype=float)
            if n.shape == pts.shape and np.isfinite(n).all():
                unit = n[keep] / np.linalg.norm(n[keep], axis=1, keepdims=True)
        pts = pts[keep]
        s = np.concatenate([[0.0], np.cumsum(step[step > LENGTH_EPS_MM])])
        if len(pts) < 2 or s[-1] <= 0:
            raise TracePolylineError(f"{field} has zero length", field=f"{field}.points", value=float(s[-1]))
        return cls(points=pts, s=s, normals=unit, slope_stretch=slope_stretch, slope=slope)

    @classmethod
    def from_dict(cls, stored: Mapping[str, Any], field: str = "trace.nominal") -> TracePolyline:
        """The stored JSON form (``Trace.nominal``, see the module doc) -> polyline.

        ``from_dict(d).to_dict()`` gives ``d`` back: points, slope stretch and slope exactly,
        normals to their stored rounding (they are renormalised when read, as the planners
        need unit normals; a stored normal is unit only to 1e-6), and consecutive duplicate
        points would be dropped (the service never stores them)."""
        if "points" not in stored:
            raise TracePolylineError(f"{field} has no points", field=f"{field}.points", value=sorted(stored))
        stretch = stored.get("slope_stretch")
        return cls.from_points(stored["points"], stored.get("normals"), field=field,
                               slope_stretch=None if stretch is None else float(stretch),
                               slope=stored.get("slope"))

    def to_dict(self) -> dict[str, Any]:
        """The stored JSON form: points and normals rounded to 1e-6 mm; keys whose value is
        unknown (normals, slope_stretch, slope) are left out."""
        out: dict[str, Any] = {"points": _rounded(self.points)}
        if self.normals is not None:
            out["normals"] = _rounded(self.normals)
        if self.slope_stretch is not None:
            out["slope_stretch"] = float(self.slope_stretch)
        if self.slope is not None:
            out["slope"] = self.slope
        return out

    # queries ------------------------------------------------------------------------------
    @property
    def length_mm(self) -> float:
        return float(self.s[-1])

    @property
    def z_range(self) -> tuple[float, float]:
        """(z min, z max) mm of the points."""
        return float(self.points[:, 2].min()), float(self.points[:, 2].max())

    def at(self, s: np.ndarray) -> np.ndarray:
        """Points (m, 3) at arc lengths ``s`` (m,) mm, linear between polyline points."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length_mm)
        return np.stack([np.interp(s, self.s, self.points[:, c]) for c in range(3)], axis=1)

    def z_at(self, s: np.ndarray) -> np.ndarray:
        """Nominal height (m,) mm at arc lengths ``s`` (m,)."""
        out: np.ndarray = np.interp(np.asarray(s, dtype=float), self.s, self.points[:, 2])
        return out

    def normals_at(self, s: np.ndarray) -> np.ndarray | None:
        """Unit normals (m, 3) at ``s`` (m,) (interpolated, renormalised) or None."""
        if self.normals is None:
            return None
        n = np.stack([np.interp(s, self.s, self.normals[:, c]) for c in range(3)], axis=1)
        out: np.ndarray = n / np.linalg.norm(n, axis=1, keepdims=True)
        return out

    def project_xy(self, xy: np.ndarray, chunk: int = 256) -> XYProjection:
        """Closest point of the top-view polyline to each query ``xy`` (m, 2) mm.

        Returns the arc length ``s`` (3-D, mm) of that point and the xy distance (mm).
        """
        q = np.atleast_2d(np.asarray(xy, dtype=float))[:, :2]
        a = self.points[:-1, :2]
        d = self.points[1:, :2] - a
        dd = np.einsum("ij,ij->i", d, d)
        safe = np.where(dd > 0, dd, 1.0)
        ds = np.diff(self.s)
        s_out = np.empty(len(q))
        dist_out = np.empty(len(q))
        for lo in range(0, len(q), chunk):
            qq = q[lo:lo + chunk, None, :]
            t = np.clip(np.einsum("mkj,kj->mk", qq - a, d) / safe, 0.0, 1.0)
            t = np.where(dd > 0, t, 0.0)
            dist2 = np.sum((a + t[..., None] * d - qq) ** 2, axis=2)
            best = np.argmin(dist2, axis=1)
            rows = np.arange(len(best))
            s_out[lo:lo + chunk] = self.s[best] + t[rows, best] * ds[best]
            dist_out[lo:lo + chunk] = np.sqrt(dist2[rows, best])
        return XYProjection(s=s_out, distance_mm=dist_out)


def as_trace_polyline(nominal: Any, field: str = "nominal") -> TracePolyline:
    """A trace polyline as is, or one made (:meth:`TracePolyline.from_points`) from anything
    with ``.points`` (k, 3) (and optionally ``.normals``) or from a bare (k, 3) array."""
    if isinstance(nominal, TracePolyline):
        return nominal
    return TracePolyline.from_points(getattr(nominal, "points", nominal), getattr(nominal, "normals", None),
                                     field=field)


def build_nominal_trace(
    mesh: trimesh.Trimesh, geometry: Mapping[str, Any], frame: Frame = "xy",
    tolerance: Tolerance = DEFAULT_TOLERANCE,
) -> TracePolyline:
    """Geometry dict (API form) + part mesh -> the trace polyline on the part's surface
    (with normals and ``slope_stretch``; ``slope`` is the caller's, see :mod:`app.geometry.slope`).

    Raises GeometryError subclasses (-> 422): bad geometry, zero length, off the surface.
    """
    curve = trace_curve(geometry, tolerance=tolerance)
    if frame == "xy":
        if curve.dimension != 2:
            raise GeometryError(
                "frame 'xy' takes top-view (x, y) coordinates; use frame '3d' for points on the surface",
                field="geometry", value=curve.dimension,
            )
        top_view = cl_points(curve, tolerance.chord_mm)
        draped = drape_polyline(mesh, top_view.points, tolerance)
        points, normals, s_mm = draped.points, draped.normals, draped.s_mm
        stretch = draped.slope_stretch
    elif frame == "3d":
        if curve.dimension != 3:
            raise GeometryError("frame '3d' takes (x, y, z) coordinates", field="geometry", value=curve.dimension)
        samples = cl_points(curve, tolerance.chord_mm)
        snapped = snap_to_surface(mesh, samples.points, tolerance.snap_mm)
        points, normals = snapped.points, snapped.normals
        s_mm = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        xy_len = float(np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1).sum())
        stretch = float(s_mm[-1] / xy_len) if xy_len > 0 else float("inf")
    else:
        raise GeometryError("frame must be 'xy' or '3d'", field="frame", value=frame)
    return TracePolyline(points=points, s=s_mm, normals=normals, slope_stretch=float(stretch))


def build_nominal_traces(
    mesh: trimesh.Trimesh, geometries: Sequence[Mapping[str, Any]], tolerance: Tolerance = DEFAULT_TOLERANCE,
) -> list[TracePolyline] | None:
    """Many frame "xy" geometry dicts -> their trace polylines, draped all at once
    (:func:`app.geometry.drape_batch.drape_polylines`): equal to :func:`build_nominal_trace`
    of each.  None when any of them is not a valid top-view trace over the part: build those
    one by one, which names the first error."""
    curves = []
    for geometry in geometries:
        try:
            curve = trace_curve(geometry, tolerance=tolerance, check_size=False)
        except (GeometryError, ValueError):
            return None
        if curve.dimension != 2:
            return None
        curves.append(curve)
    if not curves_clearly_within_limits(curves, tolerance.chord_mm, tolerance.dedup_mm):
        return None
    top_views = [c.points for c in cl_points_many(curves, tolerance.chord_mm)]
    draped = drape_polylines(mesh, top_views, tolerance)
    if draped is None:
        return None
    return [TracePolyline(points=d.points, s=d.s_mm, normals=d.normals, slope_stretch=float(d.slope_stretch))
            for d in draped]
