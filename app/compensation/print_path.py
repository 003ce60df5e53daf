"""Adaptive segmentation of a densely sampled tool path, with a per-segment proof.

The compensated (or nominal) tip path is known as a function c(s) of the nominal trace's
arc length s.  It is sampled densely, ``points`` (N, 3) at stations ``s`` (N,), and this
module picks a subset of the samples as G-code vertices so that the emitted polyline
stays within ``chord_error_mm`` of the curve:

1. **Curvature-adaptive placement.**  A circular piece of length l deviates kappa l^2 / 8
   from its chord, so the density sqrt(kappa / (8 e)) is integrated over arc length and
   a vertex is put at every whole unit of that integral (kappa from three-point circles
   on a coarser sub-grid, so polyline kinks of the nominal are seen at their true scale).
2. **Proof and repair.**  For every segment, the distance of each interior dense sample
   to the segment's chord is measured, and a *gap bound* is added: the caller states how
   far the true curve can depart from the straight line between two adjacent samples
   (``gap_bound_mm`` (N-1,)).  Distance to a segment is convex, so for any curve point
   between samples a and b: dist <= max(dist(a), dist(b)) + gap bound.  Segments whose
   bound exceeds the tolerance are split at their worst sample (or in the middle) until
   all pass.

All lengths in mm.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from app.domain.errors import InvalidInput
from app.geometry.tolerance import DEGENERATE_LENGTH_MM, LENGTH_EPS_MM

__all__ = [
    "SegmentationError",
    "SegmentedPath",
    "chord_distances",
    "dense_stations",
    "segment_adaptive",
    "segment_errors",
]

_KAPPA_SCALE_MM = 0.1  # curvature is estimated on a sub-grid of about this spacing
_MAX_ROUNDS = 200


class SegmentationError(InvalidInput):
    """The samples cannot prove the requested chord error (too coarse, non-finite)."""


class SegmentedPath(NamedTuple):
    """The emitted polyline.

    index: (k,) indices of the vertices into the dense samples.  s: (k,) their stations,
    mm.  points: (k, 3) vertices, mm.  segment_error_mm: (k-1,) proved upper bound of the
    distance between each segment and the curve it replaces.  max_error_mm: the largest.
    """

    index: np.ndarray  # type: ignore[assignment]  # the field shadows tuple.index by design
    s: np.ndarray
    points: np.ndarray
    segment_error_mm: np.ndarray
    max_error_mm: float


def dense_stations(s0: float, s1: float, step_mm: float, required: np.ndarray) -> np.ndarray:
    """Sorted stations (N,) on [s0, s1]: an even grid of at most ``step_mm`` plus every
    ``required`` station inside (e.g. the nominal polyline's vertices, where it kinks)."""
    n = max(1, int(np.ceil((s1 - s0) / step_mm)))
    grid = np.linspace(s0, s1, n + 1)
    req = np.asarray(required, dtype=float)
    req = req[(req > s0) & (req < s1)]
    merged = np.unique(np.concatenate([grid, req]))
    # drop stations closer than LENGTH_EPS_MM to a neighbour (keeps both ends)
    keep = np.concatenate([[True], np.diff(merged) > LENGTH_EPS_MM])
    merged = merged[keep]
    merged[-1] = s1
    out: np.ndarray = merged
    return out


def chord_distances(points: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Distance (N,) of every dense sample to the chord of the segment it lies in.

    points: (N, 3); index: (k,) increasing vertex indices with index[0] = 0 and
    index[-1] = N - 1.  Vertices get 0.
    """
    n = len(points)
    seg = np.clip(np.searchsorted(index, np.arange(n), side="right") - 1, 0, len(index) - 2)
    a = points[index[seg]]
    b = points[index[seg + 1]]
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    t = np.einsum("ij,ij->i", points - a, ab) / np.where(ll > 0, ll, 1.0)
    t = np.clip(np.where(ll > 0, t, 0.0), 0.0, 1.0)
    out: np.ndarray = np.linalg.norm(points - (a + t[:, None] * ab), axis=1)
    return out


def segment_errors(points: np.ndarray, index: np.ndarray,
                   gap_bound_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Proved error bound (k-1,) per segment and the distances (N,) it came from."""
    dist = chord_distances(points, index)
    starts = index[:-1]
    sampled = np.maximum.reduceat(dist, starts)
    # reduceat over [index[i], index[i+1]) misses the end vertex, whose distance is 0
    gap = np.maximum.reduceat(gap_bound_mm, starts)
    return sampled + gap, dist


def _curvature(s: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Curvature (N,) 1/mm from three-point circles on a sub-grid of ~_KAPPA_SCALE_MM."""
    n = len(s)
    spacing = max((s[-1] - s[0]) / max(n - 1, 1), DEGENERATE_LENGTH_MM)
    w = int(max(1, round(_KAPPA_SCALE_MM / spacing)))
    if n < 2 * w + 1:
        w = max(1, (n - 1) // 2)
    if n < 3:
        return np.zeros(n)
    j = np.arange(w, n - w)
    a, b, c = points[j - w], points[j], points[j + w]
    ab, bc, ac = b - a, c - b, c - a
    cross = np.linalg.norm(np.cross(ab, bc), axis=1)
    denom = (np.linalg.norm(ab, axis=1) * np.linalg.norm(bc, axis=1)
             * np.linalg.norm(ac, axis=1))
    k = np.where(denom > 0, 2.0 * cross / np.where(denom > 0, denom, 1.0), 0.0)
    out: np.ndarray = np.interp(s, s[j], k)
    return out


def _initial_vertices(s: np.ndarray, points: np.ndarray, chord_error_mm: float) -> np.ndarray:
    kappa = _curvature(s, points)
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    g = np.sqrt(kappa / (8.0 * chord_error_mm))
    density = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * step)])
    total = density[-1]
    count = max(1, int(np.ceil(total)))
    targets = np.linspace(0.0, total, count + 1)
    idx = np.searchsorted(density, targets[1:-1])
    return np.unique(np.concatenate([[0], idx, [len(s) - 1]]))


def segment_adaptive(s: np.ndarray, points: np.ndarray, chord_error_mm: float,
                     gap_bound_mm: np.ndarray | float = 0.0) -> SegmentedPath:
    """Pick vertices among dense samples so every segment is within ``chord_error_mm``.

    s: (N,) increasing stations, mm.  points: (N, 3) curve samples, mm.  gap_bound_mm:
    (N-1,) or scalar bound of the curve's departure from the straight line between
    adjacent samples.  Raises SegmentationError if a single sample interval already
    exceeds the tolerance (sample more densely) or the input is not finite.
    """
    s = np.asarray(s, dtype=float)
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or len(points) != len(s) or len(s) < 2:
        raise SegmentationError("need (N >= 2, 3) samples with (N,) stations",
                                field="points", value=list(points.shape))
    if not (np.isfinite(points).all() and np.isfinite(s).all()):
        first = int(np.argmax(~np.isfinite(points).all(axis=1)))
        raise SegmentationError(f"tool path sample {first} is not finite (s = {s[first]:.4f} mm)",
                                field="path", value=float(s[first]))
    gap = np.broadcast_to(np.asarray(gap_bound_mm, dtype=float), (len(s) - 1,))
    gap = np.concatenate([gap, [0.0]])  # pad: reduceat reads gap[index[i]..index[i+1]-1]
    if gap.max() >= chord_error_mm:
        j = int(np.argmax(gap))
        raise SegmentationError(
            f"dense samples too coarse: the curve may leave the chord of one sample interval "
            f"by {gap[j]:.2e} mm at s = {s[j]:.3f} mm (>= chord error {chord_error_mm} mm)",
            field="chord_error_mm", value=chord_error_mm)
    index = _initial_vertices(s, points, chord_error_mm)
    for _ in range(_MAX_ROUNDS):
        err, dist = segment_errors(points, index, gap)
        bad = np.flatnonzero(err > chord_error_mm)
        if bad.size == 0:
            break
        new = []
        for i in bad:
            lo, hi = int(index[i]), int(index[i + 1])
            inner = dist[lo + 1:hi]
            worst = lo + 1 + int(np.argmax(inner))
            # split at the worst sample unless it hugs an end (then halve)
            new.append(worst if lo + 1 < worst < hi - 1 else (lo + hi) // 2)
        index = np.unique(np.concatenate([index, new]))
    else:  # pragma: no cover - each round at least halves a failing segment
        raise SegmentationError("segmentation did not converge", field="chord_error_mm",
                                value=chord_error_mm)
    return SegmentedPath(index=index, s=s[index], points=points[index],
                         segment_error_mm=err, max_error_mm=float(err.max(initial=0.0)))
