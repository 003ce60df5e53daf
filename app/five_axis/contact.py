"""Contact points and nozzle directions of a trace on a fitted surface (patent S3, step 4).

The trace p(u) is a NURBS curve in workpiece coordinates that should lie on the surface.
Each trace point is projected onto the surface (closest point); the contact point is that
projection and the nozzle direction is either

* ``"surface"`` — the unit surface normal at the contact point (default: a nozzle that
  stands perpendicular to the substrate needs exactly this), or
* ``"principal"`` — the patent's principal normal of the trace curve,
  N = (p'' - (p''.T) T) / |...|, turned to the same side as the surface normal.  It is
  undefined on straight stretches and differs from the surface normal wherever the trace
  bends sideways on the surface (geodesic curvature).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from app.five_axis.errors import DegenerateTraceError, TraceOffSurfaceError
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_surface import NurbsSurface

__all__ = ["NormalSource", "NormalSide", "ContactFrames", "surface_orientation",
           "contact_frames"]

NormalSource = Literal["surface", "principal"]
NormalSide = Literal["up", "as_is", "flipped"]

#: a trace whose curvature (1/mm) is below this is straight there: its principal normal is undefined
_STRAIGHT_CURVATURE_PER_MM = 1e-9


@dataclass(frozen=True)
class ContactFrames:
    """Per-sample contact data (k samples).

    u: (k,) trace parameters; trace_points: (k,3) p(u) mm; contact: (k,3) closest surface
    points mm; uv: (k,2) their surface parameters; surface_normal: (k,3) unit, oriented;
    direction: (k,3) unit nozzle direction used (surface or principal normal);
    trace_deviation_mm: (k,) |p(u) - contact|; normal_source: which direction was used.
    """

    u: npt.NDArray[np.float64]
    trace_points: npt.NDArray[np.float64]
    contact: npt.NDArray[np.float64]
    uv: npt.NDArray[np.float64]
    surface_normal: npt.NDArray[np.float64]
    direction: npt.NDArray[np.float64]
    trace_deviation_mm: npt.NDArray[np.float64]
    normal_source: NormalSource


def surface_orientation(surface: NurbsSurface, side: NormalSide) -> float:
    """+1 or -1: the factor applied to S_u x S_v.  ``"up"`` makes the normal at the centre
    of the domain point to +Z (the side a nozzle above the part sees)."""
    if side == "as_is":
        return 1.0
    if side == "flipped":
        return -1.0
    (u0, u1), (v0, v1) = surface.domain
    n = surface.normal([(u0 + u1) / 2], [(v0 + v1) / 2])[0]
    return 1.0 if n[2] >= 0 else -1.0


def _principal_normals(trace: NurbsCurve, u: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    d = trace.derivatives(u, 2)
    d1, d2 = d[1], d[2]
    t = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    perp = d2 - np.einsum("ij,ij->i", d2, t)[:, None] * t
    kappa = np.linalg.norm(perp, axis=1) / np.einsum("ij,ij->i", d1, d1)
    straight = np.flatnonzero(kappa < _STRAIGHT_CURVATURE_PER_MM)
    if straight.size:
        j = int(straight[0])
        raise DegenerateTraceError(
            f"the trace is straight at u = {u[j]:.6g}: its principal normal is undefined; "
            "use normal='surface'", field="params.normal",
            value={"u": u[j], "curvature_per_mm": kappa[j]})
    unit: npt.NDArray[np.float64] = perp / np.linalg.norm(perp, axis=1, keepdims=True)
    return unit


def contact_frames(surface: NurbsSurface, trace: NurbsCurve, u: npt.NDArray[np.float64], *,
                   on_surface_tol_mm: float, normal_source: NormalSource = "surface",
                   normal_side: NormalSide = "up") -> ContactFrames:
    """Project trace samples p(u), u (k,), onto the surface and build the nozzle frames.

    Raises TraceOffSurfaceError (field ``"trace"``) naming the first sample farther than
    ``on_surface_tol_mm`` from the surface (e.g. a trace that runs off the fitted patch).
    """
    if trace.dimension != 3:
        raise TraceOffSurfaceError("the trace must be a 3-D curve in workpiece coordinates",
                                   field="trace.control_points", value=trace.dimension)
    u = np.asarray(u, dtype=float)
    pts = trace.evaluate(u)
    inv = surface.invert(pts)
    far = np.flatnonzero(inv.distance > on_surface_tol_mm)
    if far.size:
        j = int(far[0])
        raise TraceOffSurfaceError(
            f"the trace leaves the fitted surface: point {pts[j].round(4).tolist()} (u = "
            f"{u[j]:.6g}) is {inv.distance[j]:.4f} mm from it (tolerance "
            f"{on_surface_tol_mm} mm); {far.size} of {u.size} samples are off the surface",
            field="trace", value={"u": u[j], "point": pts[j], "distance_mm": inv.distance[j],
                                  "off_samples": int(far.size)})
    sign = surface_orientation(surface, normal_side)
    n_surf = sign * surface.normal(inv.u, inv.v)
    if normal_source == "surface":
        direction = n_surf
    elif normal_source == "principal":
        pn = _principal_normals(trace, u)
        direction = np.where((np.einsum("ij,ij->i", pn, n_surf) < 0)[:, None], -pn, pn)
    else:
        raise DegenerateTraceError("normal must be 'surface' or 'principal'",
                                   field="params.normal", value=str(normal_source))
    return ContactFrames(u=u, trace_points=pts, contact=inv.closest,
                         uv=np.column_stack([inv.u, inv.v]), surface_normal=n_surf,
                         direction=direction, trace_deviation_mm=inv.distance,
                         normal_source=normal_source)
