"""Input checks shared by curves, surfaces, fitting and trace shapes.

Each check returns a clean float64 array or raises a typed GeometryError that names the
field and the offending value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.geometry.errors import DegenerateGeometryError, GeometryError, KnotVectorError, WeightError

__all__ = [
    "as_points",
    "as_degree",
    "check_knots",
    "check_weights",
    "check_distinct_consecutive",
    "clamped_uniform_knots",
]


def as_points(value: Any, field: str, *, dims: tuple[int, ...] = (2, 3), min_count: int = 1) -> np.ndarray:
    """``value`` as a finite float array (k, d) with d in ``dims`` and k >= min_count."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise GeometryError(f"{field} must be a list of numeric points", field=field, value=value) from exc
    if arr.ndim != 2 or arr.shape[1] not in dims:
        raise GeometryError(
            f"{field} must be a list of points with {' or '.join(map(str, dims))} coordinates",
            field=field,
            value=list(arr.shape),
        )
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise DegenerateGeometryError(f"{field}[{i}] is not finite", field=f"{field}[{i}]", value=arr[i])
    if arr.shape[0] < min_count:
        raise DegenerateGeometryError(
            f"{field} needs at least {min_count} points, got {arr.shape[0]}", field=field, value=arr.shape[0]
        )
    return arr


def as_degree(value: Any, field: str) -> int:
    """A degree as a positive int (bools and non-integers rejected)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < 1:
        raise GeometryError(f"{field} must be an integer >= 1", field=field, value=value)
    return int(value)


def check_knots(knots: Any, degree: int, n_ctrl: int, field: str) -> np.ndarray:
    """Knot vector of length n_ctrl + degree + 1, finite, non-decreasing, non-empty domain."""
    try:
        t = np.asarray(knots, dtype=float)
    except (TypeError, ValueError) as exc:
        raise KnotVectorError(f"{field} must be a list of numbers", field=field, value=knots) from exc
    expected = n_ctrl + degree + 1
    if t.ndim != 1 or t.size != expected:
        raise KnotVectorError(
            f"{field} must have {expected} knots (control points + degree + 1), got {t.size}",
            field=field,
            value=int(t.size),
        )
    if not np.isfinite(t).all():
        raise KnotVectorError(f"{field} contains non-finite knots", field=field, value=t)
    dec = np.diff(t) < 0
    if dec.any():
        i = int(np.argmax(dec))
        raise KnotVectorError(
            f"{field} must be non-decreasing (knot {i + 1} < knot {i})", field=field, value=t[i : i + 2]
        )
    if not t[degree] < t[n_ctrl]:
        raise KnotVectorError(f"{field} has an empty parameter domain", field=field, value=t)
    interior = t[degree + 1 : n_ctrl]
    if interior.size:
        _, counts = np.unique(interior, return_counts=True)
        if counts.max() > degree:
            raise KnotVectorError(
                f"{field}: an interior knot repeats more than degree ({degree}) times",
                field=field,
                value=t,
            )
    return t


def check_weights(weights: Any, shape: tuple[int, ...], field: str) -> np.ndarray:
    """Weights of ``shape``, finite and strictly positive (None -> all ones)."""
    if weights is None:
        return np.ones(shape)
    try:
        w = np.asarray(weights, dtype=float)
    except (TypeError, ValueError) as exc:
        raise WeightError(f"{field} must be numbers", field=field, value=weights) from exc
    if w.shape != shape:
        raise WeightError(f"{field} must have shape {list(shape)}, got {list(w.shape)}", field=field,
                          value=list(w.shape))
    bad = ~(np.isfinite(w) & (w > 0))
    if bad.any():
        idx = np.unravel_index(int(np.argmax(bad)), shape)
        raise WeightError(
            f"{field}{list(idx)} must be positive and finite", field=field, value=float(w[idx])
        )
    return w


def check_distinct_consecutive(points: np.ndarray, dedup_mm: float, field: str) -> np.ndarray:
    """Raise if two consecutive points are closer than ``dedup_mm``; return segment lengths (k-1,)."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    dup = seg <= dedup_mm
    if dup.any():
        i = int(np.argmax(dup))
        raise DegenerateGeometryError(
            f"{field}[{i + 1}] duplicates the previous point (closer than {dedup_mm} mm)",
            field=f"{field}[{i + 1}]",
            value=points[i + 1],
        )
    out: np.ndarray = seg
    return out


def clamped_uniform_knots(n_ctrl: int, degree: int) -> np.ndarray:
    """Clamped uniform knot vector on [0, 1] with n_ctrl + degree + 1 entries."""
    inner = np.linspace(0.0, 1.0, n_ctrl - degree + 1)
    return np.concatenate([np.zeros(degree), inner, np.ones(degree)])
