"""Tensor-product NURBS surfaces.

scipy's ``NdBSpline`` evaluates the homogeneous control net ``(w*x, w*y, w*z, w)``; the
rational surface and its partial derivatives follow by the quotient rule.  Coordinates in
mm; parameters (u, v) dimensionless.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from math import comb
from typing import Any, NamedTuple

import numpy as np
import trimesh
from numpy.typing import ArrayLike
from scipy.interpolate import NdBSpline
from scipy.spatial import cKDTree

from app.geometry.errors import GeometryError
from app.geometry.nurbs import _frozen
from app.geometry.tolerance import DEFAULT_TOLERANCE, DIVISION_FLOOR, DOMAIN_SLACK_REL, ROUNDOFF_REL, Tolerance
from app.geometry.validation import (
    as_degree,
    as_points,
    check_knots,
    check_weights,
    clamped_uniform_knots,
)

__all__ = ["NurbsSurface", "SurfaceInversion", "SurfacePartials"]


@dataclass(frozen=True)
class SurfacePartials:
    """Partial derivatives, each (k, 3) mm: ``p[i][j]`` = d^(i+j) S / du^i dv^j, i + j <= order.

    ``p[0][0]`` is the point, ``p[1][0]`` = S_u, ``p[0][1]`` = S_v (entries with i + j > order are None).
    """

    d: list[list[Any]]  # np.ndarray, or None where i + j > order

    def __getitem__(self, i: int) -> list[np.ndarray]:
        return self.d[i]


class SurfaceInversion(NamedTuple):
    """Closest surface points: ``u``, ``v`` (k,), ``closest`` (k, 3) mm, ``distance`` (k,) mm."""

    u: np.ndarray
    v: np.ndarray
    closest: np.ndarray
    distance: np.ndarray


@dataclass(frozen=True, eq=False)
class NurbsSurface:
    """A tensor-product NURBS surface.

    control_points: (nu, nv, 3) mm; weights: (nu, nv) positive (None -> ones);
    knots_u: (nu + degree_u + 1,), knots_v: (nv + degree_v + 1,).
    """

    degree_u: int
    degree_v: int
    knots_u: np.ndarray
    knots_v: np.ndarray
    control_points: np.ndarray
    weights: np.ndarray | None = None  # None given -> ones (set in __post_init__; read it as ``w``)

    def __post_init__(self) -> None:
        vals = _validated(
            self.degree_u, self.degree_v, self.knots_u, self.knots_v, self.control_points, self.weights, "surface"
        )
        for name, degree in zip(("degree_u", "degree_v"), vals[:2]):
            object.__setattr__(self, name, degree)
        for name, array in zip(("knots_u", "knots_v", "control_points", "weights"), vals[2:]):
            object.__setattr__(self, name, _frozen(array))


    @property
    def w(self) -> np.ndarray:
        """The weights (never None after construction)."""
        assert self.weights is not None
        return self.weights

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((u0, u1), (v0, v1))."""
        nu, nv = self.w.shape
        return (
            (float(self.knots_u[self.degree_u]), float(self.knots_u[nu])),
            (float(self.knots_v[self.degree_v]), float(self.knots_v[nv])),
        )

    @cached_property
    def _homogeneous(self) -> NdBSpline:
        w = self.w[..., None]
        c = np.concatenate([self.control_points * w, w], axis=-1)
        return NdBSpline((self.knots_u, self.knots_v), c, (self.degree_u, self.degree_v), extrapolate=True)

    def _params(self, u: ArrayLike, v: ArrayLike) -> np.ndarray:
        uu, vv = np.broadcast_arrays(np.atleast_1d(np.asarray(u, float)), np.atleast_1d(np.asarray(v, float)))
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        for axis, (a, b), name in zip((0, 1), self.domain, ("u", "v")):
            col = uv[:, axis]
            slack = DOMAIN_SLACK_REL * max(b - a, 1.0)
            if not np.isfinite(col).all() or (col.size and (col.min() < a - slack or col.max() > b + slack)):
                raise GeometryError(f"{name} outside the surface's domain [{a}, {b}]", field=name, value=col)
            uv[:, axis] = np.clip(col, a, b)
        return uv

    def _hom(self, uv: np.ndarray, i: int, j: int) -> np.ndarray:
        if i > self.degree_u or j > self.degree_v:
            return np.zeros((uv.shape[0], 4))
        out: np.ndarray = self._homogeneous(uv, nu=(i, j))
        return out

    def evaluate(self, u: ArrayLike, v: ArrayLike) -> np.ndarray:
        """Points at (u, v) (broadcast to k) -> (k, 3) mm."""
        h = self._hom(self._params(u, v), 0, 0)
        out: np.ndarray = h[:, :3] / h[:, 3:]
        return out

    def derivatives(self, u: ArrayLike, v: ArrayLike, order: int = 1) -> SurfacePartials:
        """Rational partials S_(i,j) for i + j <= order (NURBS Book A4.4), each (k, 3) mm."""
        uv = self._params(u, v)
        hom: list[list[Any]] = [[self._hom(uv, i, j) if i + j <= order else None for j in range(order + 1)]
                                for i in range(order + 1)]
        w: list[list[Any]] = [[h[:, 3:] if h is not None else None for h in row] for row in hom]
        s: list[list[Any]] = [[None] * (order + 1) for _ in range(order + 1)]
        for k in range(order + 1):
            for l in range(order - k + 1):
                acc = hom[k][l][:, :3].copy()
                for j in range(1, l + 1):
                    acc -= comb(l, j) * w[0][j] * s[k][l - j]
                for i in range(1, k + 1):
                    acc -= comb(k, i) * w[i][0] * s[k - i][l]
                    inner = np.zeros_like(acc)
                    for j in range(1, l + 1):
                        inner += comb(l, j) * w[i][j] * s[k - i][l - j]
                    acc -= comb(k, i) * inner
                s[k][l] = acc / w[0][0]
        return SurfacePartials(s)

    def normal(self, u: ArrayLike, v: ArrayLike) -> np.ndarray:
        """Unit normals S_u x S_v at (u, v) -> (k, 3); degenerate points use a nearby interior one."""
        uv = self._params(u, v)
        d = self.derivatives(uv[:, 0], uv[:, 1], 1)
        n = np.cross(d[1][0], d[0][1])
        norm = np.linalg.norm(n, axis=1)
        bad = norm <= ROUNDOFF_REL * np.maximum(1.0, np.abs(d[0][0]).max(axis=1))
        if bad.any():
            (u0, u1), (v0, v1) = self.domain
            centre = np.array([(u0 + u1) / 2, (v0 + v1) / 2])
            nudged = uv[bad] + 1e-7 * (centre - uv[bad])
            dd = self.derivatives(nudged[:, 0], nudged[:, 1], 1)
            n[bad] = np.cross(dd[1][0], dd[0][1])
            norm = np.linalg.norm(n, axis=1)
        out: np.ndarray = n / norm[:, None]
        return out

    # ---------------------------------------------------------------- inversion
    @cached_property
    def _samples(self) -> tuple[np.ndarray, cKDTree]:
        grids = []
        for knots, (a, b), p in zip((self.knots_u, self.knots_v), self.domain, (self.degree_u, self.degree_v)):
            br = np.unique(knots[(knots >= a) & (knots <= b)])
            per = max(4, 2 * p)
            t = np.linspace(0, 1, per, endpoint=False)
            grids.append(np.append((br[:-1, None] + np.diff(br)[:, None] * t).ravel(), b))
        uu, vv = np.meshgrid(grids[0], grids[1], indexing="ij")
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        return uv, cKDTree(self.evaluate(uv[:, 0], uv[:, 1]))

    def invert(self, points: ArrayLike, tolerance: Tolerance = DEFAULT_TOLERANCE) -> SurfaceInversion:
        """Closest surface point to each of ``points`` (k, 3): dense-sample start + 2-D Newton."""
        pts = as_points(points, "points", dims=(3,))
        uvs, tree = self._samples
        _, idx = tree.query(pts)
        uv = uvs[idx].copy()
        (u0, u1), (v0, v1) = self.domain
        lo, hi = np.array([u0, v0]), np.array([u1, v1])
        for _ in range(50):
            d = self.derivatives(uv[:, 0], uv[:, 1], 2)
            r = d[0][0] - pts
            su, sv = d[1][0], d[0][1]
            g = np.column_stack([np.einsum("ij,ij->i", su, r), np.einsum("ij,ij->i", sv, r)])
            a = np.einsum("ij,ij->i", su, su) + np.einsum("ij,ij->i", d[2][0], r)
            b = np.einsum("ij,ij->i", su, sv) + np.einsum("ij,ij->i", d[1][1], r)
            c = np.einsum("ij,ij->i", sv, sv) + np.einsum("ij,ij->i", d[0][2], r)
            det = a * c - b * b
            ok = (det > 0) & (a > 0)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.column_stack([(c * g[:, 0] - b * g[:, 1]) / det, (a * g[:, 1] - b * g[:, 0]) / det])
                # fall back to a scaled gradient step where the Hessian is not positive definite
                gd = g / np.maximum(np.column_stack([np.einsum("ij,ij->i", su, su), np.einsum("ij,ij->i", sv, sv)]),
                                    DIVISION_FLOOR)
            step = np.where(ok[:, None], step, gd)
            step = np.where(np.isfinite(step), step, 0.0)
            new = np.clip(uv - step, lo, hi)
            moved = np.abs(new - uv).max(initial=0.0)
            uv = new
            if moved <= tolerance.param_rel * max(u1 - u0, v1 - v0):
                break
        closest = self.evaluate(uv[:, 0], uv[:, 1])
        return SurfaceInversion(uv[:, 0], uv[:, 1], closest, np.linalg.norm(closest - pts, axis=1))

    # ------------------------------------------------------------------ exchange
    def to_mesh(self, nu: int = 50, nv: int = 50) -> trimesh.Trimesh:
        """Triangulate an nu x nv parameter grid (>= 2 each) -> trimesh (2*(nu-1)*(nv-1) faces)."""
        if nu < 2 or nv < 2:
            raise GeometryError("mesh grid needs at least 2 x 2 samples", field="grid", value=[nu, nv])
        (u0, u1), (v0, v1) = self.domain
        uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv), indexing="ij")
        verts = self.evaluate(uu.ravel(), vv.ravel())
        idx = np.arange(nu * nv).reshape(nu, nv)
        a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
        return trimesh.Trimesh(verts, faces, process=False)

    def to_dict(self) -> dict[str, Any]:
        """API form: degree_u, degree_v, knots_u, knots_v, control_points [nu][nv][3], weights [nu][nv]."""
        return {
            "degree_u": self.degree_u,
            "degree_v": self.degree_v,
            "knots_u": self.knots_u.tolist(),
            "knots_v": self.knots_v.tolist(),
            "control_points": self.control_points.tolist(),
            "weights": self.w.tolist(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, field: str = "surface") -> NurbsSurface:
        """From the API form (knots default clamped uniform, weights 1); errors name ``field.<key>``."""
        if not isinstance(data, Mapping):
            raise GeometryError(f"{field} must be an object", field=field, value=str(type(data).__name__))
        for key in ("degree_u", "degree_v", "control_points"):
            if key not in data:
                raise GeometryError(f"{field}.{key} is required", field=f"{field}.{key}", value=None)
        vals = _validated(
            data["degree_u"], data["degree_v"], data.get("knots_u"), data.get("knots_v"),
            data["control_points"], data.get("weights"), field,
        )
        return cls(*vals)

    def to_geomdl(self) -> Any:
        """A ``geomdl.NURBS.Surface`` (control points ordered with v varying fastest)."""
        from geomdl import NURBS

        nu, nv = self.w.shape
        s = NURBS.Surface()
        s.degree_u, s.degree_v = self.degree_u, self.degree_v
        w = self.w[..., None]
        s.set_ctrlpts(np.concatenate([self.control_points * w, w], axis=-1).reshape(-1, 4).tolist(), nu, nv)
        s.knotvector_u, s.knotvector_v = self.knots_u.tolist(), self.knots_v.tolist()
        return s

    @classmethod
    def from_geomdl(cls, surface: Any) -> NurbsSurface:
        """From a geomdl ``BSpline.Surface`` or ``NURBS.Surface``."""
        nu, nv = surface.ctrlpts_size_u, surface.ctrlpts_size_v
        pts = np.asarray(surface.ctrlpts, float).reshape(nu, nv, 3)
        weights = getattr(surface, "weights", None)
        w = np.asarray(weights, float).reshape(nu, nv) if weights else None
        return cls(int(surface.degree_u), int(surface.degree_v), np.asarray(surface.knotvector_u),
                   np.asarray(surface.knotvector_v), pts, w)


def _validated(
    degree_u: Any, degree_v: Any, knots_u: Any, knots_v: Any, control_points: Any, weights: Any, field: str
) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    pu, pv = as_degree(degree_u, f"{field}.degree_u"), as_degree(degree_v, f"{field}.degree_v")
    try:
        net = np.asarray(control_points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise GeometryError(f"{field}.control_points must be a [nu][nv][3] grid", field=f"{field}.control_points",
                            value=None) from exc
    if net.ndim != 3 or net.shape[2] != 3:
        raise GeometryError(
            f"{field}.control_points must be a [nu][nv][3] grid", field=f"{field}.control_points", value=list(net.shape)
        )
    nu, nv = net.shape[:2]
    as_points(net.reshape(-1, 3), f"{field}.control_points", dims=(3,))
    if nu < pu + 1 or nv < pv + 1:
        raise GeometryError(
            f"{field}.control_points needs at least (degree_u+1) x (degree_v+1) points",
            field=f"{field}.control_points",
            value=[nu, nv],
        )
    tu = clamped_uniform_knots(nu, pu) if knots_u is None else check_knots(knots_u, pu, nu, f"{field}.knots_u")
    tv = clamped_uniform_knots(nv, pv) if knots_v is None else check_knots(knots_v, pv, nv, f"{field}.knots_v")
    w = check_weights(weights, (nu, nv), f"{field}.weights")
    return pu, pv, tu, tv, net, w
