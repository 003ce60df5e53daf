"""The nominal trace as probing and reconstruction see it: a dense 3-D polyline.

Anything with ``.points`` (k, 3) (and optionally ``.normals`` (k, 3), e.g. the geometry
core's ``NominalTrace``) or a bare (k, 3) array is accepted by :func:`as_nominal_path`.
The polyline is taken as the truth of the CAD model along the trace: for a trace draped
onto a faceted mesh it holds every triangle-edge crossing, so linear interpolation between
its points is exact for that mesh.  Arc length ``s`` (mm) is measured along it in 3-D.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from app.errors import InvalidInput


class NominalTraceError(InvalidInput):
    """A nominal trace that cannot be used (too few points, non-finite, zero length)."""


class NominalTraceLike(Protocol):
    """What the planner needs from a nominal trace."""

    points: np.ndarray


class XYProjection(NamedTuple):
    """Closest points on the nominal's top view: ``s`` (m,) mm, ``distance_mm`` (m,)."""

    s: np.ndarray
    distance_mm: np.ndarray


@dataclass(frozen=True, eq=False)
class NominalPath:
    """Dense nominal polyline.

    points: (k, 3) mm, consecutive duplicates removed.
    s: (k,) cumulative 3-D arc length, mm, s[0] = 0.
    normals: (k, 3) unit surface normals or None.
    """

    points: np.ndarray
    s: np.ndarray
    normals: np.ndarray | None = None

    @property
    def length_mm(self) -> float:
        return float(self.s[-1])

    def at(self, s: np.ndarray) -> np.ndarray:
        """Points (m, 3) at arc lengths ``s`` (m,) mm, linear between polyline points."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length_mm)
        return np.stack([np.interp(s, self.s, self.points[:, c]) for c in range(3)], axis=1)

    def z_at(self, s: np.ndarray) -> np.ndarray:
        """Nominal height (m,) mm at arc lengths ``s`` (m,)."""
        return np.interp(np.asarray(s, dtype=float), self.s, self.points[:, 2])

    def normals_at(self, s: np.ndarray) -> np.ndarray | None:
        """Unit normals (m, 3) at ``s`` (m,) (interpolated, renormalised) or None."""
        if self.normals is None:
            return None
        n = np.stack([np.interp(s, self.s, self.normals[:, c]) for c in range(3)], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

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


def as_nominal_path(nominal: Any, field: str = "nominal") -> NominalPath:
    """Normalise a nominal trace (NominalPath, object with ``.points``, or (k, 3) array)."""
    if isinstance(nominal, NominalPath):
        return nominal
    raw_points = getattr(nominal, "points", nominal)
    raw_normals = getattr(nominal, "normals", None)
    try:
        pts = np.asarray(raw_points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise NominalTraceError(f"{field}.points must be numeric", field=f"{field}.points",
                                value=str(raw_points)[:60]) from exc
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
        raise NominalTraceError(f"{field}.points must be (k >= 2, 3)", field=f"{field}.points",
                                value=list(pts.shape))
    if not np.isfinite(pts).all():
        i = int(np.argmax(~np.isfinite(pts).all(axis=1)))
        raise NominalTraceError(f"{field}.points[{i}] is not finite",
                                field=f"{field}.points[{i}]", value=str(pts[i].tolist()))
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    keep = np.concatenate([[True], step > 1e-9])
    normals = None
    if raw_normals is not None:
        n = np.asarray(raw_normals, dtype=float)
        if n.shape == pts.shape and np.isfinite(n).all():
            normals = n[keep] / np.linalg.norm(n[keep], axis=1, keepdims=True)
    pts = pts[keep]
    s = np.concatenate([[0.0], np.cumsum(step[step > 1e-9])])
    if len(pts) < 2 or s[-1] <= 0:
        raise NominalTraceError(f"{field} has zero length", field=f"{field}.points",
                                value=float(s[-1]))
    return NominalPath(points=pts, s=s, normals=normals)
