"""Tool-location (CL) points: a polyline within a chordal tolerance of a curve.

Method (FIELD_NOTES): split the curve at its C0 breaks (corners), equidistribute the
density sqrt(kappa / (8 delta)) over arc length on each piece (a circular segment of
length l has sagitta kappa*l^2/8), then *verify* every emitted segment against the curve
(dense samples between the segment's parameters, the largest refined by golden-section
search) and bisect the violators until every segment is within ``chord_mm``.

Every step runs once over all curves' pieces and segments (:class:`~app.geometry.nurbs_batch.CurveBatch`
evaluates every curve's queries together; sums run along rows, one row per piece), and each
value is computed from its own curve alone: a curve's CL points are the same bits whether
it is given alone or among a board's thousand curves.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from app.geometry.errors import GeometryError
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_batch import CurveBatch, row_search

__all__ = ["CLPoints", "cl_points", "cl_points_many", "segment_sagitta"]

_VERIFY_SAMPLES = 24
_GOLDEN_STEPS = 16  # the bracket shrinks to 0.618^16 = 5e-4 of 2/25 of the segment: the sagitta to ~1e-8 of itself
_DENSE_PER_SPAN = 32
_DENSE_MIN = 256
_MAX_BISECTIONS = 60


class CLPoints(NamedTuple):
    """u (k,) parameters, points (k, d) mm, max_sagitta_mm: the largest verified chord height."""

    u: np.ndarray
    points: np.ndarray
    max_sagitta_mm: float


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product over the last axis (d = 2 or 3), summed in a fixed order."""
    out: np.ndarray = a[..., 0] * b[..., 0]
    for j in range(1, a.shape[-1]):
        out = out + a[..., j] * b[..., j]
    return out


def _distance_to_chords(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of p (m, s, d) to segments a-b (m, d) -> (m, s)."""
    ab = b - a
    ll = _dot(ab, ab)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ll[:, None] > 0, _dot(p - a[:, None], ab[:, None]) / ll[:, None], 0.0)
    r = p - (a[:, None] + np.clip(t, 0.0, 1.0)[..., None] * ab[:, None])
    out: np.ndarray = np.sqrt(_dot(r, r))
    return out


def segment_sagitta(curve: NurbsCurve, u: np.ndarray) -> np.ndarray:
    """Largest distance from the curve to each chord C(u_i)-C(u_i+1); u (k,) -> (k-1,) mm.

    Dense samples locate the worst point, golden-section search refines it.
    """
    u = np.asarray(u, dtype=float)
    return _sagittas(CurveBatch([curve]), np.zeros(u.size - 1, dtype=np.int64), u[:-1], u[1:])


def _sagittas(batch: CurveBatch, curve: np.ndarray, a_u: np.ndarray, b_u: np.ndarray) -> np.ndarray:
    """Sagitta (m,) mm of the chords of ``curve`` (m,) between parameters ``a_u`` and ``b_u`` (m,):
    the largest of 24 samples, refined by golden-section steps (every chord at once)."""
    span_a, span_b = batch.span(curve, a_u), batch.span(curve, b_u)
    a, b = batch.evaluate(curve, a_u, span_a), batch.evaluate(curve, b_u, span_b)
    frac = np.linspace(0.0, 1.0, _VERIFY_SAMPLES + 2)[1:-1]
    samples = a_u[:, None] + (b_u - a_u)[:, None] * frac[None, :]
    dense_curve = np.repeat(curve, _VERIFY_SAMPLES)
    known = np.where(span_a == span_b, span_a, -1)  # a chord in one span: every parameter between its ends
    dense_span = np.repeat(known, _VERIFY_SAMPLES)
    dense = batch.evaluate(dense_curve, samples.ravel(), _spans(batch, dense_curve, samples.ravel(), dense_span))
    dense = dense.reshape(a.shape[0], _VERIFY_SAMPLES, -1)
    d = _distance_to_chords(dense, a, b)
    j = np.argmax(d, axis=1)
    step = (b_u - a_u) / (_VERIFY_SAMPLES + 1)
    rows = np.arange(samples.shape[0])
    lo = np.maximum(samples[rows, j] - step, a_u)
    hi = np.minimum(samples[rows, j] + step, b_u)
    best = d.max(axis=1)
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    ab = b - a
    ll = _dot(ab, ab)
    inv = np.divide(1.0, ll, out=np.zeros_like(ll), where=ll > 0)

    def dist(x: np.ndarray) -> np.ndarray:
        ap = batch.evaluate(curve, x, _spans(batch, curve, x, known)) - a
        t = np.clip(_dot(ap, ab) * inv, 0.0, 1.0)
        r = ap - t[:, None] * ab
        out: np.ndarray = np.sqrt(_dot(r, r))
        return out

    x1, x2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    f1, f2 = dist(x1), dist(x2)
    for _ in range(_GOLDEN_STEPS):
        left = f1 > f2  # maximum lies in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        nx1, nx2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        x1, x2 = np.where(left, nx1, x2), np.where(left, x1, nx2)
        fx = dist(np.where(left, x1, x2))
        f1, f2 = np.where(left, fx, f2), np.where(left, f1, fx)
        best = np.maximum(best, np.maximum(f1, f2))
    out: np.ndarray = best
    return out


def _spans(batch: CurveBatch, curve: np.ndarray, u: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Knot spans (m,) of the queries: ``known`` (m,) where it is >= 0, else searched."""
    unknown = np.flatnonzero(known < 0)
    if not unknown.size:
        return known
    out = known.copy()
    out[unknown] = batch.span(curve[unknown], u[unknown])
    return out


def _pieces(curve: NurbsCurve) -> tuple[np.ndarray, np.ndarray]:
    """Edges of the parameter intervals between C0 breaks (interior knots of multiplicity
    >= degree) (k + 1,), and the knot spans in each interval (k,)."""
    a, b = curve.domain
    knots, counts = np.unique(curve.knots, return_counts=True)
    breaks = knots[(counts >= curve.degree) & (knots > a) & (knots < b)]
    edges = np.concatenate([[a], breaks, [b]])
    inside = knots[(knots >= a) & (knots <= b)]
    return edges, np.diff(np.searchsorted(inside, edges))


def _linspace_rows(a: np.ndarray, b: np.ndarray, count: int) -> np.ndarray:
    """``np.linspace(a_i, b_i, count)`` of each row: (p,), (p,) -> (p, count)."""
    out: np.ndarray = np.arange(count)[None, :] * ((b - a) / (count - 1))[:, None] + a[:, None]
    out[:, -1] = b
    return out


def _equidistributed(batch: CurveBatch, curve: np.ndarray, a: np.ndarray, b: np.ndarray, count: int,
                     chord_mm: float) -> list[np.ndarray]:
    """Parameters of each piece (``curve`` (p,) on [a, b] (p,)) at equal steps of the point
    density's integral, from ``count`` samples per piece."""
    u = _linspace_rows(a, b, count)
    d = batch.derivatives(np.repeat(curve, count), u.ravel(), 2)
    speed = np.sqrt(_dot(d[1], d[1])).reshape(u.shape)
    du = np.diff(u, axis=1)
    s = np.concatenate([np.zeros((u.shape[0], 1)), np.cumsum(0.5 * (speed[:, 1:] + speed[:, :-1]) * du, axis=1)],
                       axis=1)
    g = np.sqrt(batch.curvature(d) / (8.0 * chord_mm)).reshape(u.shape)
    big_g = np.concatenate([np.zeros((u.shape[0], 1)),
                            np.cumsum(0.5 * (g[:, 1:] + g[:, :-1]) * np.diff(s, axis=1), axis=1)], axis=1)
    n = np.maximum(1, np.ceil(big_g[:, -1])).astype(np.int64)
    spread = (n > 1) & (s[:, -1] > 0)
    rows = np.repeat(np.flatnonzero(spread), n[spread] + 1)
    k = np.arange(rows.size) - np.repeat(np.cumsum(n[spread] + 1) - (n[spread] + 1), n[spread] + 1)
    targets = np.where(k == n[rows], big_g[rows, -1], k * (big_g[rows, -1] / n[rows]))
    found = _interp_rows(targets, big_g, u, rows)
    out = [np.array([lo, hi]) for lo, hi in zip(a, b)]
    for r, part in zip(np.flatnonzero(spread), np.split(found, np.cumsum(n[spread] + 1)[:-1])):
        out[r] = part
    return out


def _interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``np.interp(x_i, xp[rows_i], fp[rows_i])`` for each query (xp rows non-decreasing)."""
    width = xp.shape[1]
    j = np.clip(row_search(xp.ravel(), rows * width, np.full(rows.size, width), x) - 1, 0, width - 2)
    x0, x1, f0, f1 = xp[rows, j], xp[rows, j + 1], fp[rows, j], fp[rows, j + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        out: np.ndarray = np.where(x1 > x0, (f1 - f0) / (x1 - x0) * (x - x0) + f0, f0)
    return np.where(x >= xp[rows, -1], fp[rows, -1], out)


def cl_points(curve: NurbsCurve, chord_mm: float) -> CLPoints:
    """CL points along ``curve`` so that no segment deviates more than ``chord_mm`` from it.

    Returns parameters (k,), points (k, d) mm and the largest verified sagitta (mm) which
    is <= chord_mm.  Corners (C0 breaks) are always CL points.
    """
    return cl_points_many([curve], chord_mm)[0]


def cl_points_many(curves: list[NurbsCurve], chord_mm: float) -> list[CLPoints]:
    """:func:`cl_points` of each curve (the same points), every curve of one dimension at once."""
    if not (isinstance(chord_mm, (int, float)) and np.isfinite(chord_mm) and chord_mm > 0):
        raise GeometryError("chord tolerance must be positive and finite", field="chord_mm", value=chord_mm)
    out: list[CLPoints | None] = [None] * len(curves)
    todo: dict[int, list[int]] = {}
    for i, curve in enumerate(curves):
        if curve.degree == 1 and not curve.is_rational:  # straight pieces: exactly their ends, sagitta 0
            u = _pieces(curve)[0]
            out[i] = CLPoints(u, curve.evaluate(u), 0.0)
            continue
        todo.setdefault(curve.dimension, []).append(i)
    for members in todo.values():
        for i, found in zip(members, _curved([curves[i] for i in members], chord_mm)):
            out[i] = found
    return [p for p in out if p is not None]


def _curved(curves: list[NurbsCurve], chord_mm: float) -> list[CLPoints]:
    """CL points of curves of one dimension: pieces equidistributed, chords verified and
    bisected until within ``chord_mm``."""
    batch = CurveBatch(curves)
    pieces = [_pieces(curve) for curve in curves]
    piece_curve = np.repeat(np.arange(len(curves)), [len(spans) for _, spans in pieces])
    piece_a = np.concatenate([edges[:-1] for edges, _ in pieces])
    piece_b = np.concatenate([edges[1:] for edges, _ in pieces])
    count = np.maximum(_DENSE_MIN, _DENSE_PER_SPAN * np.concatenate([spans for _, spans in pieces]))
    piece_u: list[np.ndarray] = [np.empty(0)] * piece_a.size
    for c in np.unique(count):
        sel = np.flatnonzero(count == c)
        for i, u in zip(sel, _equidistributed(batch, piece_curve[sel], piece_a[sel], piece_b[sel], int(c), chord_mm)):
            piece_u[i] = u
    u_curve = np.concatenate([np.arange(len(curves)), np.repeat(piece_curve, [u.size - 1 for u in piece_u])])
    u_all = np.concatenate([[curve.domain[0] for curve in curves], *(u[1:] for u in piece_u)])
    order = np.lexsort((u_all, u_curve))
    u_curve, u_all = u_curve[order], u_all[order]
    keep = np.concatenate([[True], (u_curve[1:] != u_curve[:-1]) | (u_all[1:] != u_all[:-1])])
    u_curve, u_all = u_curve[keep], u_all[keep]
    inner = u_curve[1:] == u_curve[:-1]  # consecutive parameters of one curve: its segments
    seg_curve, seg_a, seg_b = u_curve[:-1][inner], u_all[:-1][inner], u_all[1:][inner]
    sag = _sagittas(batch, seg_curve, seg_a, seg_b)
    for _ in range(_MAX_BISECTIONS):
        bad = sag > chord_mm
        if not bad.any():
            break
        # each violator becomes its two halves, in place; only the halves are verified again
        idx = np.repeat(np.arange(sag.size), np.where(bad, 2, 1))
        second = np.concatenate([[False], idx[1:] == idx[:-1]])
        first = bad[idx] & ~second
        mid = 0.5 * (seg_a + seg_b)[idx]
        seg_curve = seg_curve[idx]
        seg_a = np.where(second, mid, seg_a[idx])
        seg_b = np.where(first, mid, seg_b[idx])
        split = np.flatnonzero(bad[idx])
        sag = sag[idx]
        sag[split] = _sagittas(batch, seg_curve[split], seg_a[split], seg_b[split])
    else:  # pragma: no cover - bisection halves the sagitta each round
        raise GeometryError("could not meet the chord tolerance", field="chord_mm", value=chord_mm)
    starts = np.flatnonzero(np.concatenate([[True], seg_curve[1:] != seg_curve[:-1]]))
    point_curve = np.concatenate([seg_curve, seg_curve[np.append(starts[1:] - 1, seg_curve.size - 1)]])
    point_u = np.concatenate([seg_a, seg_b[np.append(starts[1:] - 1, seg_curve.size - 1)]])
    order = np.lexsort((point_u, point_curve))
    point_curve, point_u = point_curve[order], point_u[order]
    points = batch.evaluate(point_curve, point_u)
    bounds = np.flatnonzero(np.concatenate([[True], point_curve[1:] != point_curve[:-1], [True]]))
    worst = np.maximum(np.maximum.reduceat(sag, starts), 0.0)
    return [CLPoints(point_u[lo:hi], points[lo:hi], float(w)) for lo, hi, w in zip(bounds[:-1], bounds[1:], worst)]
