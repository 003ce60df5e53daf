"""Measured probe points -> clean deviation samples along the nominal trace.

Steps: validate (finite, (k, 3)), place each point on the nominal by its xy (arc length s,
mm), deviation dz = z_measured - z_nominal(s), sort by s, merge repeated measurements of
one station (mean; or refuse them), then reject outliers robustly: each point's dz is
compared with a quadratic through its neighbours (up to two each side, itself left out);
the worst point whose residual exceeds ``max(k_mad * 1.4826 * MAD, k_sigma * sigma,
floor)`` is dropped and the test repeated.  Deviation of a real part from CAD is smooth,
so a spike (chip, dust, probe bounce) stands out against its neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from app.domain.errors import InvalidInput
from app.geometry.tolerance import LENGTH_EPS_MM
from app.geometry.traces import TracePolyline


class ReconstructionError(InvalidInput):
    """Measured points or parameters that cannot be reconstructed (422)."""


@dataclass(frozen=True)
class PreprocessParams:
    """Preprocessing settings (mm).

    sigma_mm: probe repeatability (1 sigma).  max_offset_mm: largest xy distance of a
    measured point from the nominal trace.  dedup_mm: two points closer than this along
    the trace are one station.  duplicates: "merge" (average repeats) or "error".
    outliers: reject outliers (needs >= min_points_outliers points).  A point is an
    outlier when its leave-one-out residual exceeds max(k_mad * robust sigma of all
    residuals, k_sigma * sigma_mm, outlier_floor_mm); the two end points on each side
    are predicted by extrapolation, so their residual is divided by end_factor first.
    """

    sigma_mm: float = 0.001
    max_offset_mm: float = 0.5
    dedup_mm: float = 1e-3
    duplicates: str = "merge"
    outliers: bool = True
    k_mad: float = 6.0
    k_sigma: float = 6.0
    outlier_floor_mm: float = 0.03
    end_factor: float = 4.0
    min_points_outliers: int = 6


@dataclass(frozen=True, eq=False)
class CleanPoints:
    """Clean, sorted measurement (mm).

    points: (n, 3) kept points (merged repeats averaged).  s: (n,) arc length on the
    nominal.  dz: (n,) measured - nominal height.  outliers: indices into the *input*
    array of rejected points.  merged: number of input points merged into others.
    """

    points: np.ndarray
    s: np.ndarray
    dz: np.ndarray
    outliers: tuple[int, ...]
    merged: int


def validate_measured(measured: Any, field: str = "points") -> np.ndarray:
    """Measured points as a finite (k, 3) float array, else ReconstructionError."""
    try:
        pts = np.asarray(measured, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ReconstructionError(f"{field} must be numeric [[x, y, z], ...]", field=field,
                                  value=str(measured)[:60]) from exc
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ReconstructionError(f"{field} must be a list of [x, y, z]", field=field,
                                  value=list(pts.shape))
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ReconstructionError(f"{field}[{i}] is not finite", field=f"{field}[{i}]",
                                  value=[str(v) for v in pts[i]])
    return pts


def loo_residuals(s: np.ndarray, dz: np.ndarray) -> np.ndarray:
    """Leave-one-out residuals (n,): dz_i minus a quadratic through up to 2 neighbours
    on each side (fewer at the ends, then taking more from the other side; >= 4 used)."""
    n = len(s)
    out = np.empty(n)
    for i in range(n):
        lo, hi = max(0, i - 2), min(n, i + 3)
        while hi - lo - 1 < 4 and (lo > 0 or hi < n):
            lo, hi = (lo - 1, hi) if lo > 0 and (hi >= n or i - lo <= hi - i) else (lo, hi + 1)
        idx = np.array([j for j in range(lo, hi) if j != i])
        deg = min(2, len(idx) - 1)
        scale = max(np.ptp(s[idx]), LENGTH_EPS_MM)
        coef = np.polyfit((s[idx] - s[i]) / scale, dz[idx], deg)
        out[i] = dz[i] - coef[-1]
    return out


def reject_outliers(s: np.ndarray, dz: np.ndarray, params: PreprocessParams) -> np.ndarray:
    """Boolean mask (n,) of inliers, removing the worst offender one at a time."""
    keep = np.ones(len(s), dtype=bool)
    while keep.sum() >= params.min_points_outliers:
        idx = np.flatnonzero(keep)
        r = loo_residuals(s[idx], dz[idx])
        mad = 1.4826 * np.median(np.abs(r - np.median(r)))
        limit = max(params.k_mad * mad, params.k_sigma * params.sigma_mm,
                    params.outlier_floor_mm)
        # the two points at each end are predicted by extrapolation: looser limit
        scale = np.ones(len(idx))
        scale[:2] = scale[-2:] = params.end_factor
        score = np.abs(r) / scale
        worst = int(np.argmax(score))
        if score[worst] <= limit:
            break
        keep[idx[worst]] = False
    return keep


def preprocess(path: TracePolyline, measured: Any, params: PreprocessParams,
               field: str = "points") -> CleanPoints:
    """Clean measured points (k, 3) against the nominal ``path`` (see module doc)."""
    pts = validate_measured(measured, field)
    if len(pts) == 0:
        raise ReconstructionError(f"{field} is empty", field=field, value=0)
    proj = path.project_xy(pts[:, :2])
    far = proj.distance_mm > params.max_offset_mm
    if far.any():
        i = int(np.argmax(far))
        raise ReconstructionError(
            f"{field}[{i}] is {proj.distance_mm[i]:.3f} mm from the trace in xy "
            f"(> {params.max_offset_mm} mm): not a measurement of this trace",
            field=f"{field}[{i}]", value=pts[i].tolist())
    order = np.argsort(proj.s, kind="stable")
    s, p = proj.s[order], pts[order]
    dz = p[:, 2] - path.z_at(s)
    groups = np.concatenate([[0], np.cumsum(np.diff(s) > params.dedup_mm)])
    merged = len(s) - int(groups[-1]) - 1
    if merged and params.duplicates == "error":
        i = int(order[np.argmax(np.diff(groups) == 0) + 1])
        raise ReconstructionError(f"{field}[{i}] duplicates another measured point",
                                  field=f"{field}[{i}]", value=pts[i].tolist())
    if merged:
        count = np.bincount(groups)
        s = np.bincount(groups, s) / count
        dz = np.bincount(groups, dz) / count
        p = np.stack([np.bincount(groups, p[:, c]) / count for c in range(3)], axis=1)
        first = np.concatenate([[0], np.flatnonzero(np.diff(groups)) + 1])
        ids = order[first]
    else:
        ids = order
    keep = reject_outliers(s, dz, params) if params.outliers else np.ones(len(s), bool)
    outliers = tuple(sorted(int(i) for i in ids[~keep]))
    return CleanPoints(points=p[keep], s=s[keep], dz=dz[keep], outliers=outliers, merged=merged)
