"""Rational B-spline (NURBS) curves of any degree and dimension 2 or 3.

scipy is the numeric engine (``BSpline`` on homogeneous coordinates ``(w*x, w*y[, w*z], w)``,
divided back: exact), geomdl is the exchange format and the test oracle.  Units: mm for
coordinates, the parameter ``u`` is dimensionless (the knot vector's domain).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from math import comb
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from app.geometry.errors import GeometryError
from app.geometry.tolerance import DEFAULT_TOLERANCE, DIVISION_FLOOR, DOMAIN_SLACK_REL, Tolerance
from app.geometry.validation import as_degree, as_points, check_knots, check_weights

__all__ = ["NurbsCurve", "CurveInversion"]

GAUSS_X, GAUSS_W = np.polynomial.legendre.leggauss(16)  # arc length: 16 nodes on each piece,
PIECES_PER_SPAN = 4  # 4 pieces per knot span


class CurveInversion(NamedTuple):
    """Closest points on a curve: ``u`` (k,), ``closest`` (k, d) mm, ``distance`` (k,) mm."""

    u: np.ndarray
    closest: np.ndarray
    distance: np.ndarray


def rational_derivatives(hom: np.ndarray) -> np.ndarray:
    """The rational curve's derivatives d^k C / du^k, k = 0..K, from the homogeneous ones
    ``hom`` (K + 1, m, d + 1) (the weighted point and the weight last): the quotient rule
    A^(k) = sum_i C(k, i) w^(i) C^(k-i) solved for C^(k) -> (K + 1, m, d)."""
    a, w = hom[..., :-1], hom[..., -1:]
    out = np.empty_like(a)
    for k in range(len(hom)):
        acc = a[k].copy()
        for i in range(1, k + 1):
            acc -= comb(k, i) * w[i] * out[k - i]
        out[k] = acc / w[0]
    return out


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class NurbsCurve:
    """A NURBS curve.

    degree: p >= 1; knots: (n+p+2,) non-decreasing; control_points: (n+1, d) mm with d in
    {2, 3}; weights: (n+1,) positive (None -> all ones).  Validated on construction; the
    arrays are stored as read-only float64 copies.
    """

    degree: int
    knots: np.ndarray
    control_points: np.ndarray
    weights: np.ndarray | None = None  # None given -> ones (set in __post_init__; read it as ``w``)

    def __post_init__(self) -> None:
        degree, knots, points, weights = _validated(
            self.degree, self.knots, self.control_points, self.weights, "curve"
        )
        object.__setattr__(self, "degree", degree)
        object.__setattr__(self, "knots", _frozen(knots))
        object.__setattr__(self, "control_points", _frozen(points))
        object.__setattr__(self, "weights", _frozen(weights))

    # ------------------------------------------------------------------ basics

    @property
    def w(self) -> np.ndarray:
        """The weights (never None after construction)."""
        assert self.weights is not None
        return self.weights

    @property
    def dimension(self) -> int:
        """Number of coordinates per point (2 or 3)."""
        return int(self.control_points.shape[1])

    @property
    def domain(self) -> tuple[float, float]:
        """Parameter interval ``(knots[p], knots[n+1])``."""
        n = self.control_points.shape[0]
        return float(self.knots[self.degree]), float(self.knots[n])

    @property
    def is_rational(self) -> bool:
        """True if the weights are not all equal."""
        return bool(np.ptp(self.w) > 0)

    @cached_property
    def _homogeneous(self) -> BSpline:
        w = self.w[:, None]
        c = np.hstack([self.control_points * w, w])
        return BSpline(self.knots, c, self.degree, extrapolate=True)

    @property
    def homogeneous_spline(self) -> BSpline:
        """The curve in homogeneous coordinates (w*x, w*y[, w*z], w) as a scipy BSpline: for
        hot loops whose parameters are known to lie in the domain (no check, no clipping)."""
        return self._homogeneous

    def _params(self, u: ArrayLike, field: str = "u") -> np.ndarray:
        arr = np.atleast_1d(np.asarray(u, dtype=float)).ravel()
        a, b = self.domain
        slack = DOMAIN_SLACK_REL * max(b - a, 1.0)
        if not np.isfinite(arr).all() or (arr.size and (arr.min() < a - slack or arr.max() > b + slack)):
            raise GeometryError(
                f"parameter outside the curve's domain [{a}, {b}] or not finite", field=field, value=arr
            )
        out: np.ndarray = np.clip(arr, a, b)
        return out

    # -------------------------------------------------------------- evaluation
    def evaluate(self, u: ArrayLike) -> np.ndarray:
        """Points at parameters ``u`` (k,) -> (k, d) mm."""
        h = self._homogeneous(self._params(u))
        out: np.ndarray = h[:, :-1] / h[:, -1:]
        return out

    def derivatives(self, u: ArrayLike, order: int = 2) -> np.ndarray:
        """Rational derivatives d^i C / du^i for i = 0..order at ``u`` (k,) -> (order+1, k, d)."""
        uu = self._params(u)
        return rational_derivatives(np.stack([self._hom_derivative(uu, i) for i in range(order + 1)]))

    def _hom_derivative(self, u: np.ndarray, nu: int) -> np.ndarray:
        if nu > self.degree:
            return np.zeros((u.size, self.dimension + 1))
        out: np.ndarray = self._homogeneous(u, nu=nu)
        return out

    def curvature(self, u: ArrayLike, derivatives: np.ndarray | None = None) -> np.ndarray:
        """Curvature |C' x C''| / |C'|^3 at ``u`` (k,) -> (k,) in 1/mm (0 where C' = 0);
        ``derivatives``: :meth:`derivatives` (u, 2) when the caller has them already."""
        d = self.derivatives(u, 2) if derivatives is None else derivatives
        d1, d2 = d[1], d[2]
        s2 = np.einsum("ij,ij->i", d1, d1)
        if self.dimension == 2:
            cross = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        else:
            cross = np.linalg.norm(np.cross(d1, d2), axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            kappa = cross / s2**1.5
        return np.where(s2 > 0, kappa, 0.0)

    def speed(self, u: ArrayLike) -> np.ndarray:
        """|dC/du| at ``u`` (k,) -> (k,) mm per unit parameter."""
        out: np.ndarray = np.linalg.norm(self.derivatives(u, 1)[1], axis=1)
        return out

    # -------------------------------------------------------------- arc length
    @cached_property
    def _length_table(self) -> tuple[np.ndarray, np.ndarray]:
        a, b = self.domain
        br = np.unique(self.knots[(self.knots >= a) & (self.knots <= b)])
        parts = [np.linspace(br[i], br[i + 1], PIECES_PER_SPAN + 1)[:-1] for i in range(br.size - 1)]
        edges = np.append(np.concatenate(parts), b)
        lengths = self._gauss_length(edges[:-1], edges[1:])
        return edges, np.concatenate([[0.0], np.cumsum(lengths)])

    def _gauss_length(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        half = 0.5 * (hi - lo)
        nodes = (0.5 * (hi + lo))[:, None] + half[:, None] * GAUSS_X[None, :]
        speed = self.speed(nodes.ravel()).reshape(nodes.shape)
        out: np.ndarray = half * (speed @ GAUSS_W)
        return out

    def _length_to(self, u: np.ndarray) -> np.ndarray:
        edges, cum = self._length_table
        j = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, edges.size - 2)
        out: np.ndarray = cum[j] + self._gauss_length(edges[j], u)
        return out

    @property
    def length(self) -> float:
        """Total arc length in mm (a degree-1 curve: its control polygon's, exactly)."""
        if self.degree == 1:
            return float(np.linalg.norm(np.diff(self.control_points, axis=0), axis=1).sum())
        return float(self._length_table[1][-1])

    def arc_length(self, u0: float | None = None, u1: float | None = None) -> float:
        """Arc length in mm between parameters u0 and u1 (defaults: the domain ends)."""
        a, b = self.domain
        lo, hi = self._params([a if u0 is None else u0, b if u1 is None else u1])
        return float(self._length_to(np.array([hi]))[0] - self._length_to(np.array([lo]))[0])

    def param_at_length(self, s: ArrayLike, tolerance: Tolerance = DEFAULT_TOLERANCE) -> np.ndarray:
        """Parameters (k,) at arc lengths ``s`` (k,) mm from the start (inverse arc length).

        The length table brackets each target; safeguarded Newton refines to
        ``tolerance.length_rel`` of the total length.
        """
        edges, cum = self._length_table
        total = cum[-1]
        ss = np.atleast_1d(np.asarray(s, dtype=float)).ravel()
        slack = DOMAIN_SLACK_REL * max(total, 1.0)
        if not np.isfinite(ss).all() or (ss.size and (ss.min() < -slack or ss.max() > total + slack)):
            raise GeometryError(f"arc length outside [0, {total}] mm", field="s", value=ss)
        ss = np.clip(ss, 0.0, total)
        j = np.clip(np.searchsorted(cum, ss, side="right") - 1, 0, edges.size - 2)
        lo, hi = edges[j].copy(), edges[j + 1].copy()
        seg = cum[j + 1] - cum[j]
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(seg > 0, (ss - cum[j]) / seg, 0.0)
        u = lo + frac * (hi - lo)
        goal = tolerance.length_rel * max(total, DIVISION_FLOOR)
        for _ in range(60):
            f = self._length_to(u) - ss
            done = np.abs(f) <= goal
            if done.all():
                break
            hi = np.where(f > 0, u, hi)
            lo = np.where(f < 0, u, lo)
            sp = self.speed(u)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = u - f / sp
            bad = ~np.isfinite(step) | (step <= lo) | (step >= hi)
            u = np.where(done, u, np.where(bad, 0.5 * (lo + hi), step))
        out: np.ndarray = u
        return out

    # ---------------------------------------------------------------- inversion
    @cached_property
    def _samples(self) -> tuple[np.ndarray, cKDTree]:
        edges, _ = self._length_table
        per_piece = max(4, 2 * self.degree)
        t = np.linspace(0.0, 1.0, per_piece, endpoint=False)
        u = np.append((edges[:-1, None] + np.diff(edges)[:, None] * t[None, :]).ravel(), edges[-1])
        return u, cKDTree(self.evaluate(u))

    def invert(self, points: ArrayLike, tolerance: Tolerance = DEFAULT_TOLERANCE) -> CurveInversion:
        """Closest curve point to each of ``points`` (k, d) mm (point inversion).

        Global search on dense samples (two nearest as starts), then Newton on
        C'(u).(C(u) - P) = 0 clipped to the domain; the better of the two wins.
        """
        pts = as_points(points, "points", dims=(self.dimension,))
        us, tree = self._samples
        _, idx = tree.query(pts, k=min(2, us.size))
        idx = np.atleast_2d(idx.T).reshape(-1, pts.shape[0]) if idx.ndim > 1 else idx[None, :]
        best_u = np.full(pts.shape[0], np.nan)
        best_d = np.full(pts.shape[0], np.inf)
        for starts in idx:
            u = self._newton(us[starts], pts, tolerance)
            d = np.linalg.norm(self.evaluate(u) - pts, axis=1)
            better = d < best_d
            best_u = np.where(better, u, best_u)
            best_d = np.where(better, d, best_d)
        closest = self.evaluate(best_u)
        return CurveInversion(best_u, closest, np.linalg.norm(closest - pts, axis=1))

    def _newton(self, u: np.ndarray, pts: np.ndarray, tolerance: Tolerance) -> np.ndarray:
        a, b = self.domain
        u = u.astype(float).copy()
        for _ in range(40):
            d = self.derivatives(u, 2)
            r = d[0] - pts
            f = np.einsum("ij,ij->i", d[1], r)
            s2 = np.einsum("ij,ij->i", d[1], d[1])
            fp = np.einsum("ij,ij->i", d[2], r) + s2
            denom = np.where(fp > 0, fp, s2 + DIVISION_FLOOR)
            step = np.where(s2 > 0, f / denom, 0.0)
            u_new = np.clip(u - step, a, b)
            moved = np.abs(u_new - u)
            u = u_new
            if moved.max(initial=0.0) <= tolerance.param_rel * (b - a):
                break
        return u

    # ------------------------------------------------------------------ exchange
    def to_dict(self) -> dict[str, Any]:
        """API form ``{degree, knots, control_points, weights}`` as JSON lists."""
        return {
            "degree": self.degree,
            "knots": self.knots.tolist(),
            "control_points": self.control_points.tolist(),
            "weights": self.w.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, field: str = "curve") -> NurbsCurve:
        """Build from the API form; knots default to clamped uniform, weights to 1.

        Errors name ``field`` + the key, e.g. ``"curve.knots"``.
        """
        if not isinstance(data, Mapping):
            raise GeometryError(f"{field} must be an object", field=field, value=str(type(data).__name__))
        for key in ("degree", "control_points"):
            if key not in data:
                raise GeometryError(f"{field}.{key} is required", field=f"{field}.{key}", value=None)
        degree, knots, points, weights = _validated(
            data["degree"], data.get("knots"), data["control_points"], data.get("weights"), field
        )
        return cls(degree, knots, points, weights)

    def to_geomdl(self) -> Any:
        """A ``geomdl.NURBS.Curve`` with the same degree, knots, points and weights."""
        from geomdl import NURBS

        c = NURBS.Curve()
        c.degree = self.degree
        w = self.w[:, None]
        c.ctrlptsw = np.hstack([self.control_points * w, w]).tolist()
        c.knotvector = self.knots.tolist()
        return c

    @classmethod
    def from_geomdl(cls, curve: Any) -> NurbsCurve:
        """From a geomdl ``BSpline.Curve`` or ``NURBS.Curve``."""
        weights = getattr(curve, "weights", None)
        return cls(int(curve.degree), np.asarray(curve.knotvector), np.asarray(curve.ctrlpts), weights or None)


def _validated(
    degree: Any, knots: Any, control_points: Any, weights: Any, field: str
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Check and normalise curve data; errors name ``field.<key>``."""
    from app.geometry.validation import clamped_uniform_knots

    p = as_degree(degree, f"{field}.degree")
    pts = as_points(control_points, f"{field}.control_points", min_count=p + 1)
    n = pts.shape[0]
    t = clamped_uniform_knots(n, p) if knots is None else check_knots(knots, p, n, f"{field}.knots")
    w = check_weights(weights, (n,), f"{field}.weights")
    return p, t, pts, w
