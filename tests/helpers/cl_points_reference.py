"""A reference for :mod:`app.geometry.cl_points`: the same method with every curve evaluated
by its own :class:`~app.geometry.nurbs.NurbsCurve` (scipy's ``BSpline``), one curve at a
time (each curve's pieces equidistributed and its violators bisected on their own).  The
service's batched CL points must equal these to round-off.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from app.geometry.errors import GeometryError
from app.geometry.nurbs import NurbsCurve

__all__ = ["reference_cl_points"]

_VERIFY_SAMPLES = 24
_GOLDEN_STEPS = 16  # the bracket shrinks to 0.618^16 = 5e-4 of 2/25 of the segment: the sagitta to ~1e-8 of itself
_DENSE_PER_SPAN = 32
_DENSE_MIN = 256


class CLPoints(NamedTuple):
    """u (k,) parameters, points (k, d) mm, max_sagitta_mm: the largest verified chord height."""

    u: np.ndarray
    points: np.ndarray
    max_sagitta_mm: float


def _distance_to_chords(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of p (m, s, d) to segments a-b (m, d) -> (m, s)."""
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ll[:, None] > 0, np.einsum("isj,ij->is", p - a[:, None], ab) / ll[:, None], 0.0)
    foot = a[:, None] + np.clip(t, 0.0, 1.0)[..., None] * ab[:, None]
    out: np.ndarray = np.linalg.norm(p - foot, axis=-1)
    return out


def segment_sagitta(curve: NurbsCurve, u: np.ndarray) -> np.ndarray:
    """Largest distance from the curve to each chord C(u_i)-C(u_i+1); u (k,) -> (k-1,) mm.

    Dense samples locate the worst point, golden-section search refines it.
    """
    return _sagittas([curve], [np.asarray(u, dtype=float)])[0]


def _sagittas(curves: list[NurbsCurve], us: list[np.ndarray]) -> list[np.ndarray]:
    """:func:`segment_sagitta` of several curves of one dimension at once: the golden-section
    steps run once over every curve's segments (each curve's spline evaluated on its own)."""
    counts = np.array([u.size - 1 for u in us])
    bounds = np.concatenate([[0], np.cumsum(counts)])
    a_u = np.concatenate([u[:-1] for u in us])
    b_u = np.concatenate([u[1:] for u in us])
    ends = [curve.evaluate(u) for curve, u in zip(curves, us)]
    a = np.concatenate([e[:-1] for e in ends])
    b = np.concatenate([e[1:] for e in ends])
    frac = np.linspace(0.0, 1.0, _VERIFY_SAMPLES + 2)[1:-1]
    samples = a_u[:, None] + (b_u - a_u)[:, None] * frac[None, :]
    dense = np.concatenate([curve.evaluate(samples[lo:hi].ravel()).reshape(hi - lo, _VERIFY_SAMPLES, -1)
                            for curve, lo, hi in zip(curves, bounds[:-1], bounds[1:])])
    d = _distance_to_chords(dense, a, b)
    j = np.argmax(d, axis=1)
    step = (b_u - a_u) / (_VERIFY_SAMPLES + 1)
    lo = np.maximum(samples[np.arange(samples.shape[0]), j] - step, a_u)
    hi = np.minimum(samples[np.arange(samples.shape[0]), j] + step, b_u)
    best = d.max(axis=1)
    ratio = (np.sqrt(5.0) - 1.0) / 2.0

    splines = [curve.homogeneous_spline for curve in curves]  # x stays inside [a_u, b_u]: no domain check
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    inv = np.divide(1.0, ll, out=np.zeros_like(ll), where=ll > 0)

    def dist(x: np.ndarray) -> np.ndarray:
        h = splines[0](x) if len(splines) == 1 else \
            np.concatenate([f(x[i:k]) for f, i, k in zip(splines, bounds[:-1], bounds[1:])])
        ap = h[:, :-1] / h[:, -1:] - a
        t = np.clip(np.einsum("ij,ij->i", ap, ab) * inv, 0.0, 1.0)
        r = ap - t[:, None] * ab
        out: np.ndarray = np.sqrt(np.einsum("ij,ij->i", r, r))
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
    return [best[i:k] for i, k in zip(bounds[:-1], bounds[1:])]


def _pieces(curve: NurbsCurve) -> list[tuple[float, float]]:
    """Parameter intervals between C0 breaks (interior knots of multiplicity >= degree)."""
    a, b = curve.domain
    knots, counts = np.unique(curve.knots, return_counts=True)
    breaks = knots[(counts >= curve.degree) & (knots > a) & (knots < b)]
    edges = np.concatenate([[a], breaks, [b]])
    return list(zip(edges[:-1], edges[1:]))


def _equidistributed(curve: NurbsCurve, a: float, b: float, chord_mm: float) -> np.ndarray:
    knots = np.unique(curve.knots[(curve.knots >= a) & (curve.knots <= b)])
    count = max(_DENSE_MIN, _DENSE_PER_SPAN * (knots.size - 1))
    u = np.linspace(a, b, count)
    d = curve.derivatives(u, 2)
    speed = np.linalg.norm(d[1], axis=1)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(u))])
    g = np.sqrt(curve.curvature(u, d) / (8.0 * chord_mm))
    big_g = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(s))])
    n = max(1, int(np.ceil(big_g[-1])))
    if n == 1 or s[-1] <= 0:
        return np.array([a, b])
    targets = np.linspace(0.0, big_g[-1], n + 1)
    return np.interp(targets, big_g, u)


def reference_cl_points(curve: NurbsCurve, chord_mm: float) -> CLPoints:
    """CL points of one curve, evaluated by scipy: parameters (k,), points (k, d) mm and
    the largest verified sagitta (mm)."""
    return _one_by_one([curve], chord_mm)[0]


def _one_by_one(curves: list[NurbsCurve], chord_mm: float) -> list[CLPoints]:
    """CL points of each curve (called with one)."""
    if not (isinstance(chord_mm, (int, float)) and np.isfinite(chord_mm) and chord_mm > 0):
        raise GeometryError("chord tolerance must be positive and finite", field="chord_mm", value=chord_mm)
    out: list[CLPoints | None] = [None] * len(curves)
    todo: dict[int, list[tuple[int, np.ndarray]]] = {}
    for i, curve in enumerate(curves):
        start = np.array([curve.domain[0]])
        pieces = _pieces(curve)
        if curve.degree == 1 and not curve.is_rational:  # straight pieces: exactly their ends, sagitta 0
            u = np.unique(np.concatenate([start, [b for _, b in pieces]]))
            out[i] = CLPoints(u, curve.evaluate(u), 0.0)
            continue
        u = np.unique(np.concatenate([start, *(_equidistributed(curve, a, b, chord_mm)[1:] for a, b in pieces)]))
        todo.setdefault(curve.dimension, []).append((i, u))
    for group in todo.values():
        sags = _sagittas([curves[i] for i, _ in group], [u for _, u in group])
        for (i, u), sag in zip(group, sags):
            out[i] = _refined(curves[i], u, sag, chord_mm)
    return [p for p in out if p is not None]


def _refined(curve: NurbsCurve, u: np.ndarray, sag: np.ndarray, chord_mm: float) -> CLPoints:
    """Bisect the segments of parameters ``u`` (k,) whose sagitta ``sag`` (k-1,) passes ``chord_mm``."""
    for _ in range(60):
        bad = sag > chord_mm
        if not bad.any():
            break
        mids = 0.5 * (u[:-1][bad] + u[1:][bad])
        new_u = np.sort(np.concatenate([u, mids]))
        # keep the verified sagitta of untouched segments, re-verify only the split ones
        keep = dict(zip(zip(u[:-1][~bad], u[1:][~bad]), sag[~bad]))
        pairs = list(zip(new_u[:-1], new_u[1:]))
        todo = np.array([k not in keep for k in pairs])
        new_sag = np.empty(len(pairs))
        new_sag[~todo] = [keep[k] for k, t in zip(pairs, todo) if not t]
        idx = np.flatnonzero(todo)
        if idx.size:
            seg_u = np.column_stack([new_u[idx], new_u[idx + 1]])
            new_sag[idx] = _sagitta_pairs(curve, seg_u)
        u, sag = new_u, new_sag
    else:  # pragma: no cover - bisection halves the sagitta each round
        raise GeometryError("could not meet the chord tolerance", field="chord_mm", value=chord_mm)
    return CLPoints(u, curve.evaluate(u), float(sag.max(initial=0.0)))


def _sagitta_pairs(curve: NurbsCurve, seg_u: np.ndarray) -> np.ndarray:
    """segment_sagitta for increasing, non-overlapping parameter pairs (m, 2) -> (m,).

    The pairs are chained into one parameter list; the in-between chords are discarded.
    """
    flat = seg_u.ravel()
    sag = segment_sagitta(curve, flat)
    return sag[0::2]
