"""Ball-centre readings -> surface heights: stylus radius and pre-travel compensation (pure).

A vertical probe move down onto a locally planar surface ``z = h(x, y)`` with outward unit
normal ``n`` (n_z > 0) first touches when the ball centre is at height ``h(x0, y0) + r / n_z``
above the station (the ball rests on the tilted plane, touching it at ``centre - r n``); the
probe triggers ``delta(n)`` further down.  So (SPEC16 conventions)

    z_read = h(x0, y0) + r / n_z - delta(n)        h = z_read + delta(n) - r / n_z

and the contact point is ``c - r n`` with ``c = (x0, y0, z_read + delta(n))``.  ``h`` is the
*station-equivalent height*: the surface height exactly under the station (exact for planes;
the curvature term ``kappa (r sin theta)^2 / 2`` is below 0.5 um for our parts and ignored).
The uncorrected error ``r (1/n_z - 1) - delta`` is 32 um for r = 0.5 mm at 20 deg.

The normal is the plan's nominal normal at first; ``tilted_normals`` gives the normal of the
nominal surface plus a reconstructed deviation field, so the caller can iterate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.calibration.errors import CalibrationError
from app.calibration.model import ProbeCalibration, as_normals

__all__ = ["SurfaceReadings", "surface_heights", "tilted_normals", "MIN_NORMAL_Z"]

MIN_NORMAL_Z = 0.05   # steeper than ~87 deg a vertical probe cannot reach the surface by its bottom


@dataclass(frozen=True)
class SurfaceReadings:
    """Corrected vertical readings.

    z_mm (n,): station-equivalent surface heights (mm).  contact_mm (n, 3): where the ball
    touched the surface (mm).  correction_mm (n,): z_mm - reading z (mm, to add to a reading).
    """

    z_mm: npt.NDArray[np.float64]
    contact_mm: npt.NDArray[np.float64]
    correction_mm: npt.NDArray[np.float64]


def _readings(readings: npt.ArrayLike) -> npt.NDArray[np.float64]:
    arr = np.asarray(readings, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise CalibrationError("readings must have shape (n, 3) (mm)", field="readings", value=list(arr.shape))
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise CalibrationError(f"readings[{i}] is not finite", field=f"readings[{i}]", value=arr[i])
    return arr


def surface_heights(readings: npt.ArrayLike, normals: npt.ArrayLike, probe: ProbeCalibration | None, *,
                    radius: bool = True,
                    pretravel: bool = True) -> SurfaceReadings:
    """Station-equivalent heights of vertical readings (n, 3) mm with outward normals (n, 3).

    ``probe`` None is today's ideal probe (identity).  ``radius`` / ``pretravel`` False switch
    that part of the correction off (ablation).  Raises CalibrationError for a normal that
    points down or is steeper than ``MIN_NORMAL_Z`` (naming its index).
    """
    p = _readings(readings)
    if probe is None or (not radius and not pretravel):
        return SurfaceReadings(z_mm=p[:, 2].copy(), contact_mm=p.copy(), correction_mm=np.zeros(len(p)))
    n = as_normals(normals)
    if n.shape != p.shape:
        raise CalibrationError(f"normals must match readings ({len(p)}, 3)", field="normals", value=list(n.shape))
    steep = n[:, 2] < MIN_NORMAL_Z
    if steep.any():
        i = int(np.flatnonzero(steep)[0])
        raise CalibrationError(f"normals[{i}] is too steep for a vertical touch (n_z < {MIN_NORMAL_Z})",
                               field=f"normals[{i}]", value=n[i])
    r = probe.ball_radius_mm if radius else 0.0
    delta = probe.pretravel.at(n) if pretravel else np.zeros(len(p))
    correction = delta - r / n[:, 2]
    centre = p.copy()
    centre[:, 2] += delta
    return SurfaceReadings(z_mm=p[:, 2] + correction, contact_mm=centre - r * n, correction_mm=correction)


def tilted_normals(nominal_normals: npt.ArrayLike, deviation_gradient: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Unit normals (n, 3) of the nominal surface plus a deviation field.

    nominal_normals (n, 3): outward normals of the nominal surface (n_z > 0).
    deviation_gradient (n, 2): (d dev / dx, d dev / dy) of the deviation field (dimensionless).
    The surface gradient is ``g_nom + g_dev`` with ``g_nom = (-n_x / n_z, -n_y / n_z)``, and
    the normal is ``unit(-g_x, -g_y, 1)``.
    """
    n = as_normals(nominal_normals, "nominal_normals")
    g = np.asarray(deviation_gradient, dtype=float)
    if g.shape != (len(n), 2):
        raise CalibrationError(f"deviation_gradient must have shape ({len(n)}, 2)", field="deviation_gradient",
                               value=list(g.shape))
    if not np.isfinite(g).all():
        raise CalibrationError("deviation_gradient must be finite", field="deviation_gradient")
    down = n[:, 2] < MIN_NORMAL_Z
    if down.any():
        i = int(np.flatnonzero(down)[0])
        raise CalibrationError(f"nominal_normals[{i}] does not face up (n_z < {MIN_NORMAL_Z})",
                               field=f"nominal_normals[{i}]", value=n[i])
    gx = -n[:, 0] / n[:, 2] + g[:, 0]
    gy = -n[:, 1] / n[:, 2] + g[:, 1]
    out = np.stack([-gx, -gy, np.ones(len(n))], axis=1)
    unit: npt.NDArray[np.float64] = out / np.linalg.norm(out, axis=1)[:, None]
    return unit
