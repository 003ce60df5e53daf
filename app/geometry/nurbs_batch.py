"""Many NURBS curves evaluated together: one set of numpy calls for every curve's queries.

:class:`NurbsCurve` evaluates one curve through scipy's ``BSpline``; a board of a thousand
curves sampled at a few points each pays that call's overhead a thousand times.
:class:`CurveBatch` holds the curves' knots and homogeneous control points (and those of
their derivative curves) in flat arrays and evaluates any mix of (curve, parameter) queries
at once: each query's knot span by a binary search inside its own curve's knots (or given
by the caller), then that span's polynomial by Horner's rule.  The polynomials (homogeneous
coefficients about the span's left knot) are made once per curve set from the Cox-de Boor
triangle (NURBS Book A2.2) and the derivative curves' control points.  Every query's value
is computed by elementwise operations on that query alone, so it does not depend on which
other queries share the call (a curve evaluated alone gives the same bits as in a batch);
it equals :meth:`NurbsCurve.evaluate` / :meth:`NurbsCurve.derivatives` to round-off.
Parameters must lie in their curve's domain (no check).  Units: mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from math import factorial

import numpy as np

from app.geometry.nurbs import NurbsCurve, rational_derivatives

__all__ = ["CurveBatch", "row_search"]


def row_search(values: np.ndarray, start: np.ndarray, count: np.ndarray, x: np.ndarray) -> np.ndarray:
    """For each query, how many of ``values[start : start + count]`` (sorted) are <= ``x``:
    a binary search per query, all at once.  start, count, x (m,) -> (m,) int64."""
    lo = start.astype(np.int64)
    hi = lo + count
    last = max(values.size - 1, 0)
    for _ in range(int(count.max(initial=0)).bit_length()):
        mid = (lo + hi) >> 1
        active = lo < hi
        right = values[np.minimum(mid, last)] <= x
        lo = np.where(active & right, mid + 1, lo)
        hi = np.where(active & ~right, mid, hi)
    out: np.ndarray = lo - start
    return out


class _Degree:
    """The curves of one degree p: knots flat (K,) with each curve's start and count, and
    for each derivative order k <= p the homogeneous control points of the k-th derivative
    curve flat (sum(n_i + 1 - k), d + 1) with each curve's start."""

    def __init__(self, curves: Sequence[NurbsCurve]) -> None:
        self.p = p = curves[0].degree
        self.knots = np.concatenate([c.knots for c in curves])
        self.knot_count = np.array([c.knots.size for c in curves])
        self.knot_start = np.concatenate([[0], np.cumsum(self.knot_count)[:-1]])
        self.n_ctrl = np.array([c.control_points.shape[0] for c in curves])
        points = np.concatenate([np.hstack([c.control_points * c.w[:, None], c.w[:, None]]) for c in curves])
        curve_of_point = np.repeat(np.arange(len(curves)), self.n_ctrl)
        index_in_curve = np.arange(points.shape[0]) - np.repeat(np.cumsum(self.n_ctrl) - self.n_ctrl, self.n_ctrl)
        self.points = [points]
        self.point_start = [np.concatenate([[0], np.cumsum(self.n_ctrl)[:-1]])]
        for k in range(1, p + 1):  # Q^k_i = (p-k+1) (Q^{k-1}_{i+1} - Q^{k-1}_i) / (U_{i+p+1} - U_{i+k}), i <= n-k
            prev, owner, i = self.points[-1], curve_of_point, index_in_curve
            keep = np.flatnonzero(i < (self.n_ctrl[owner] - k))  # every point of a curve but its last
            base = self.knot_start[owner[keep]] + i[keep]
            span = self.knots[base + p + 1] - self.knots[base + k]
            safe = np.where(span > 0, span, 1.0)
            diff = (p - k + 1) * (prev[keep + 1] - prev[keep]) / safe[:, None]
            self.points.append(np.where(span[:, None] > 0, diff, 0.0))
            curve_of_point, index_in_curve = owner[keep], i[keep]
            self.point_start.append(np.concatenate([[0], np.cumsum(self.n_ctrl - k)[:-1]]))
        # each span's homogeneous polynomial about its left knot: H(u) = sum_k C_k (u - U[s])^k,
        # C_k = H^(k)(U[s]) / k! (Cox-de Boor on the span itself); taylor[nu][k - nu] holds
        # k! / (k - nu)! C_k, the coefficients of the nu-th derivative
        spans = self.n_ctrl - p  # s = p..n
        self.span_start = np.concatenate([[0], np.cumsum(spans)[:-1]])
        curve_of_span = np.repeat(np.arange(len(curves)), spans)
        s = p + np.arange(curve_of_span.size) - np.repeat(self.span_start, spans)
        u0 = self.knots[self.knot_start[curve_of_span] + s]
        with np.errstate(divide="ignore", invalid="ignore"):  # empty spans (never looked up): nan
            differences = self.differences(curve_of_span, u0, s)
            taylor = [self.homogeneous(curve_of_span, s, k, differences) / factorial(k) for k in range(p + 1)]
        self.taylor = [np.stack([factorial(k) // factorial(k - nu) * taylor[k] for k in range(nu, p + 1)])
                       for nu in range(p + 1)]

    def span(self, curve: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Knot span s (m,) with U[s] <= u < U[s+1] (the last non-empty span at the domain's end)."""
        found = row_search(self.knots, self.knot_start[curve], self.knot_count[curve], u) - 1
        out: np.ndarray = np.clip(found, self.p, self.n_ctrl[curve] - 1)
        return out

    def polynomial(self, curve: np.ndarray, u: np.ndarray, span: np.ndarray, nu: int) -> np.ndarray:
        """The nu-th homogeneous derivative (m, d + 1) from the span's polynomial (Horner in
        u - U[s])."""
        if nu > self.p:
            return np.zeros((u.size, self.points[0].shape[1]))
        t = (u - self.knots[self.knot_start[curve] + span])[:, None]
        row = self.span_start[curve] + span - self.p
        coefficients = self.taylor[nu]
        out: np.ndarray = coefficients[-1][row]
        for k in range(coefficients.shape[0] - 2, -1, -1):
            out = out * t + coefficients[k][row]
        return out

    def differences(self, curve: np.ndarray, u: np.ndarray, span: np.ndarray) -> tuple[list[np.ndarray], ...]:
        """u - U[s+1-j] and U[s+j] - u for j = 0..p, each (m,): the knot differences of the
        basis functions (shared by every derivative order)."""
        base = self.knot_start[curve] + span
        return ([u - self.knots[base + 1 - j] for j in range(self.p + 1)],
                [self.knots[base + j] - u for j in range(self.p + 1)])

    def homogeneous(self, curve: np.ndarray, span: np.ndarray, nu: int,
                    differences: tuple[list[np.ndarray], ...]) -> np.ndarray:
        """The nu-th derivative in homogeneous coordinates (m, d + 1): the degree p - nu
        derivative curve's basis functions (Cox-de Boor) times its control points."""
        q = self.p - nu
        if q < 0:
            return np.zeros((span.size, self.points[0].shape[1]))
        left, right = differences
        basis = [np.ones(span.size)]
        for j in range(1, q + 1):
            saved = np.zeros(span.size)
            for r in range(j):
                temp = basis[r] / (right[r + 1] + left[j - r])
                basis[r] = saved + right[r + 1] * temp
                saved = left[j - r] * temp
            basis.append(saved)
        first = self.point_start[nu][curve] + span - self.p
        points = self.points[nu]
        out: np.ndarray = basis[0][:, None] * points[first]
        for r in range(1, q + 1):
            out += basis[r][:, None] * points[first + r]
        return out


class CurveBatch:
    """Curves of one dimension (2 or 3), of any degrees; queries name a curve by its index
    in ``curves``."""

    def __init__(self, curves: Sequence[NurbsCurve]) -> None:
        if not curves or len({c.dimension for c in curves}) != 1:
            raise ValueError("a curve batch takes one or more curves of one dimension")
        self.curves = list(curves)
        self.dimension = curves[0].dimension
        degrees = np.array([c.degree for c in curves])
        self._groups: list[tuple[np.ndarray, _Degree]] = []
        self._group_of = np.empty(len(curves), dtype=np.int64)
        self._index_in_group = np.empty(len(curves), dtype=np.int64)
        for g, p in enumerate(np.unique(degrees)):
            members = np.flatnonzero(degrees == p)
            self._groups.append((members, _Degree([curves[int(i)] for i in members])))
            self._group_of[members] = g
            self._index_in_group[members] = np.arange(members.size)

    def span(self, curve: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The knot span (m,) of each query (``curve`` (m,), ``u`` (m,)): s with
        U[s] <= u < U[s+1] in that curve's knots (the last non-empty span at the domain's end)."""
        out = np.empty(u.size, dtype=np.int64)
        group = self._group_of[curve]
        for g, (_, degree) in enumerate(self._groups):
            sel = slice(None) if len(self._groups) == 1 else np.flatnonzero(group == g)
            out[sel] = degree.span(self._index_in_group[curve[sel]], u[sel])
        return out

    def homogeneous_derivatives(self, curve: np.ndarray, u: np.ndarray, order: int,
                                span: np.ndarray | None = None) -> np.ndarray:
        """Homogeneous derivatives 0..order of ``curve`` (m,) at ``u`` (m,) -> (order + 1, m, d + 1);
        ``span``: the queries' knot spans (:meth:`span`) when the caller knows them."""
        u = np.asarray(u, dtype=float)
        out = np.empty((order + 1, u.size, self.dimension + 1))
        group = self._group_of[curve]
        for g, (_, degree) in enumerate(self._groups):
            sel = slice(None) if len(self._groups) == 1 else np.flatnonzero(group == g)
            local, uu = self._index_in_group[curve[sel]], u[sel]
            s = degree.span(local, uu) if span is None else span[sel]
            for nu in range(order + 1):
                out[nu, sel] = degree.polynomial(local, uu, s, nu)
        return out

    def evaluate(self, curve: np.ndarray, u: np.ndarray, span: np.ndarray | None = None) -> np.ndarray:
        """Points (m, d) mm of ``curve`` (m,) at ``u`` (m,) (``span``: as for :meth:`homogeneous_derivatives`)."""
        h = self.homogeneous_derivatives(curve, u, 0, span)[0]
        out: np.ndarray = h[:, :-1] / h[:, -1:]
        return out

    def derivatives(self, curve: np.ndarray, u: np.ndarray, order: int = 2) -> np.ndarray:
        """Rational derivatives d^i C / du^i, i = 0..order -> (order + 1, m, d), by the same
        formula as :meth:`NurbsCurve.derivatives`."""
        return rational_derivatives(self.homogeneous_derivatives(curve, u, order))

    def curvature(self, derivatives: np.ndarray) -> np.ndarray:
        """Curvature (m,) 1/mm from :meth:`derivatives` (order >= 2), as :meth:`NurbsCurve.curvature`."""
        d1, d2 = derivatives[1], derivatives[2]
        s2 = d1[:, 0] * d1[:, 0] + d1[:, 1] * d1[:, 1]
        if self.dimension == 2:
            cross = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        else:
            s2 = s2 + d1[:, 2] * d1[:, 2]
            c = np.cross(d1, d2)
            cross = np.sqrt(c[:, 0] * c[:, 0] + c[:, 1] * c[:, 1] + c[:, 2] * c[:, 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            kappa = cross / s2**1.5
        out: np.ndarray = np.where(s2 > 0, kappa, 0.0)
        return out
