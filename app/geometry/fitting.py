"""Curve and surface fitting with scipy numerics (The NURBS Book, ch. 9).

Global interpolation (A9.1) = ``make_interp_spline`` with our own chord-length (or
centripetal) parameters and averaged knots (Eq. 9.8): the same control points as
``geomdl.fitting.interpolate_curve`` at a fraction of the cost.  Least squares with the end
points interpolated (A9.6, knots Eq. 9.68-9.69), smoothing splines (``make_splprep``),
tensor-product surface interpolation (A9.4) and penalised least-squares surface fitting.
All coordinates in mm; parameters on [0, 1].
"""

from __future__ import annotations

import warnings
from typing import Literal, NamedTuple

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.interpolate import BSpline, make_interp_spline, make_splprep
from scipy.linalg import solveh_banded
from scipy.sparse.linalg import MatrixRankWarning, spsolve

from app.geometry.errors import DegenerateGeometryError, GeometryError
from app.geometry.nurbs import NurbsCurve
from app.geometry.nurbs_surface import NurbsSurface
from app.geometry.tolerance import DEFAULT_TOLERANCE, DIVISION_FLOOR, DOMAIN_SLACK_REL, Tolerance
from app.geometry.validation import as_degree, as_points, check_distinct_consecutive

__all__ = [
    "Parametrization",
    "curve_parameters",
    "averaged_knots",
    "approximation_knots",
    "interpolate_curve",
    "approximate_curve",
    "smooth_curve",
    "grid_parameters",
    "grid_knots",
    "interpolate_surface",
    "SurfaceFit",
    "fit_surface",
    "approximate_surface",
]

Parametrization = Literal["chord", "centripetal"]


def curve_parameters(
    points: ArrayLike, parametrization: Parametrization = "chord", *, tolerance: Tolerance = DEFAULT_TOLERANCE,
    field: str = "points",
) -> np.ndarray:
    """Parameters (n,) on [0, 1] for points (n, d): accumulated chord length (Eq. 9.5) or its square root (9.6).

    Raises DegenerateGeometryError for consecutive duplicates (closer than ``tolerance.dedup_mm``).
    """
    pts = as_points(points, field, min_count=2)
    seg = check_distinct_consecutive(pts, tolerance.dedup_mm, field)
    if parametrization == "centripetal":
        seg = np.sqrt(seg)
    elif parametrization != "chord":
        raise GeometryError("parametrization must be 'chord' or 'centripetal'", field="parametrization",
                            value=parametrization)
    u = np.concatenate([[0.0], np.cumsum(seg)])
    out: np.ndarray = u / u[-1]
    return out


def averaged_knots(params: np.ndarray, degree: int) -> np.ndarray:
    """Clamped knots by averaging (Eq. 9.8): (n + p + 2,) for params (n + 1,)."""
    n = params.size - 1
    csum = np.concatenate([[0.0], np.cumsum(params)])
    j = np.arange(1, n - degree + 1)
    inner = (csum[j + degree] - csum[j]) / degree
    return np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])


def approximation_knots(params: np.ndarray, n_control: int, degree: int) -> np.ndarray:
    """Clamped knots for least squares with n_control control points (Eq. 9.68-9.69)."""
    m = params.size - 1
    n = n_control - 1
    d = (m + 1) / (n - degree + 1)
    j = np.arange(1, n - degree + 1)
    i = np.floor(j * d).astype(int)
    alpha = j * d - i
    inner = (1 - alpha) * params[i - 1] + alpha * params[i]
    return np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])


def _check_count(pts: np.ndarray, degree: int, field: str) -> None:
    if pts.shape[0] < degree + 1:
        raise DegenerateGeometryError(
            f"{field}: degree {degree} needs at least {degree + 1} points, got {pts.shape[0]}",
            field=field,
            value=pts.shape[0],
        )


def interpolate_curve(
    points: ArrayLike, degree: int = 3, parametrization: Parametrization = "chord", *,
    tolerance: Tolerance = DEFAULT_TOLERANCE, field: str = "points",
) -> NurbsCurve:
    """Global interpolation (A9.1): a non-rational clamped curve through every point.

    points: (n, d) mm, n >= degree + 1, no consecutive duplicates -> NurbsCurve with n
    control points, domain [0, 1], C(u_k) = Q_k at the chord-length parameters u_k.
    """
    p = as_degree(degree, "degree")
    pts = as_points(points, field)
    _check_count(pts, p, field)
    u = curve_parameters(pts, parametrization, tolerance=tolerance, field=field)
    t = averaged_knots(u, p)
    spl = make_interp_spline(u, pts, k=p, t=t)
    return NurbsCurve(p, t, spl.c, None)


def approximate_curve(
    points: ArrayLike, n_control: int, degree: int = 3, params: ArrayLike | None = None, *,
    tolerance: Tolerance = DEFAULT_TOLERANCE, field: str = "points",
) -> NurbsCurve:
    """Least-squares curve with the end points interpolated (A9.6).

    points: (m, d) mm; n_control in [degree + 1, m]; params: optional (m,) increasing on
    [0, 1] (default chord length).  Knots by Eq. 9.68-9.69.
    """
    p = as_degree(degree, "degree")
    pts = as_points(points, field)
    _check_count(pts, p, field)
    if isinstance(n_control, bool) or not isinstance(n_control, (int, np.integer)) or not (
        max(p + 1, 2) <= n_control <= pts.shape[0]
    ):
        raise GeometryError(
            f"n_control must be an integer in [{p + 1}, {pts.shape[0]}]", field="n_control", value=n_control
        )
    if params is None:
        u = curve_parameters(pts, "chord", tolerance=tolerance, field=field)
    else:
        u = np.asarray(params, dtype=float).ravel()
        if u.shape != (pts.shape[0],) or not np.isfinite(u).all() or np.any(np.diff(u) < 0) or u[0] != 0 or u[-1] != 1:
            raise GeometryError("params must be non-decreasing from 0 to 1, one per point", field="params", value=u)
    t = approximation_knots(u, int(n_control), p)
    ctrl = np.empty((int(n_control), pts.shape[1]))
    ctrl[0], ctrl[-1] = pts[0], pts[-1]
    if n_control > 2:
        n_mat = BSpline.design_matrix(u, t, p).tocsc()
        inner = n_mat[1:-1, 1:-1]
        rhs = pts[1:-1] - n_mat[1:-1, [0]].toarray() * pts[0] - n_mat[1:-1, [n_control - 1]].toarray() * pts[-1]
        ctrl[1:-1] = _solve_normal(inner, rhs, field)
    return NurbsCurve(p, t, ctrl, None)


def _solve_normal(design: sp.sparray, rhs: np.ndarray, field: str, penalty: sp.sparray | None = None) -> np.ndarray:
    """Solve min |design x - rhs|^2 (+ x' penalty x) via sparse normal equations (SuperLU)."""
    a = (design.T @ design).tocsc()
    if penalty is not None:
        a = (a + penalty).tocsc()
    b = design.T @ rhs
    with warnings.catch_warnings():
        warnings.simplefilter("error", MatrixRankWarning)
        try:
            x = spsolve(a, b)
        except (MatrixRankWarning, RuntimeError) as exc:
            raise DegenerateGeometryError(
                f"{field}: the points do not determine the fit (too few or badly spread)", field=field, value=None
            ) from exc
    x = np.asarray(x).reshape(b.shape)
    if not np.isfinite(x).all():
        raise DegenerateGeometryError(f"{field}: the fit is singular", field=field, value=None)
    return x


def _banded_upper(a: sp.sparray) -> np.ndarray:
    """LAPACK upper band storage (w + 1, n), Fortran order, of a symmetric sparse a (n, n)
    whose non-zeros lie within w of the diagonal: ab[w + i - j, j] = a[i, j], i <= j."""
    a = sp.csr_array(a)
    rows = np.repeat(np.arange(a.shape[0]), np.diff(a.indptr))
    width = int((a.indices - rows).max(initial=0))
    del rows
    ab = np.zeros((width + 1, a.shape[0]), order="F")  # LAPACK's layout: solved in place, no copy
    for k in range(width + 1):
        ab[width - k, k:] = a.diagonal(k)
    return ab


def _solve_banded_spd(a: sp.sparray | np.ndarray, rhs: np.ndarray, field: str) -> np.ndarray:
    """Solve a @ x = rhs for a symmetric positive definite a (n, n) of small bandwidth w
    (sparse, or already in :func:`_banded_upper` storage) by a banded Cholesky: (w + 1) n
    doubles, n w^2 flops.  rhs (n,) or (n, d).  Raises DegenerateGeometryError when a is not
    positive definite."""
    ab = a if isinstance(a, np.ndarray) else _banded_upper(a)
    try:
        x = solveh_banded(ab, rhs, overwrite_ab=True, check_finite=False)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise DegenerateGeometryError(
            f"{field}: the points do not determine the fit (too few or badly spread)", field=field, value=None
        ) from exc
    if not np.isfinite(x).all():
        raise DegenerateGeometryError(f"{field}: the fit is singular", field=field, value=None)
    out: np.ndarray = x
    return out


def _solve_tensor_grid(bu: sp.sparray, bv: sp.sparray, grid: np.ndarray, field: str) -> np.ndarray:
    """Least squares of a tensor-product surface on a point grid, separated by direction.

    bu (nu, mu), bv (nv, mv): the B-spline design matrices of the grid parameters; grid
    (nu, nv, d) -> control net (mu, mv, d) minimising sum |sum_ab bu[i, a] bv[j, b] C[a, b] -
    grid[i, j]|^2.  The design is bu (x) bv, whose pseudo-inverse is bu^+ (x) bv^+: the fit is
    the 1-D least squares along u of every grid column, then along v of every result row:
    two banded solves of mu and mv unknowns (bandwidth = degree), O(nu nv) memory, instead of
    the (mu mv)-unknown normal equations.
    """
    nu, nv, d = grid.shape
    mu, mv = bu.shape[1], bv.shape[1]
    bu, bv = sp.csr_array(bu), sp.csr_array(bv)
    along_u = _solve_banded_spd(bu.T @ bu, bu.T @ grid.reshape(nu, nv * d), field)  # (mu, nv*d)
    rows = along_u.reshape(mu, nv, d).transpose(1, 0, 2).reshape(nv, mu * d)
    along_v = _solve_banded_spd(bv.T @ bv, bv.T @ rows, field)  # (mv, mu*d)
    return along_v.reshape(mv, mu, d).transpose(1, 0, 2)


def _net_order(n_u: int, n_v: int) -> np.ndarray:
    """Permutation (n_u n_v,) of the net's unknowns (u-major) putting the longer direction
    first, so the normal matrix's bandwidth is degree * min(n_u, n_v) + degree."""
    index = np.arange(n_u * n_v).reshape(n_u, n_v)
    return (index.T if n_v > n_u else index).ravel()


def smooth_curve(
    points: ArrayLike, sigma_mm: float, degree: int = 3, *, tolerance: Tolerance = DEFAULT_TOLERANCE,
    field: str = "points",
) -> NurbsCurve:
    """Smoothing spline for noisy points (m, d) with per-coordinate noise ``sigma_mm``.

    scipy ``make_splprep`` on chord-length parameters with s = m * d * sigma^2 (the
    expected residual sum of squares); fewer knots where the data allow it.
    """
    p = as_degree(degree, "degree")
    pts = as_points(points, field)
    _check_count(pts, p, field)
    if not (isinstance(sigma_mm, (int, float)) and np.isfinite(sigma_mm) and sigma_mm > 0):
        raise GeometryError("sigma_mm must be positive and finite", field="sigma_mm", value=sigma_mm)
    u = curve_parameters(pts, "chord", tolerance=tolerance, field=field)
    s = pts.shape[0] * pts.shape[1] * float(sigma_mm) ** 2
    spl, _ = make_splprep(pts.T, u=u, k=p, s=s)
    t = np.asarray(spl.t)
    c = np.asarray(spl.c)  # (n_coef, d); scipy may pad it beyond len(t) - p - 1
    return NurbsCurve(p, t, c[: t.size - p - 1], None)


def grid_parameters(grid: np.ndarray, axis: int, tolerance: Tolerance, field: str) -> np.ndarray:
    """Averaged chord-length parameters along ``axis`` of a point grid (nu, nv, 3) (A9.3)."""
    g = np.moveaxis(grid, axis, 0)
    seg = np.linalg.norm(np.diff(g, axis=0), axis=-1)  # (n-1, other)
    total = seg.sum(axis=0)
    ok = total > tolerance.dedup_mm
    if not ok.any():
        raise DegenerateGeometryError(f"{field}: the grid has zero extent along axis {axis}", field=field, value=axis)
    cum = np.vstack([np.zeros((1, seg.shape[1])), np.cumsum(seg, axis=0)])[:, ok] / total[ok]
    u = cum.mean(axis=1)
    if np.any(np.diff(u) <= 0):
        raise DegenerateGeometryError(f"{field}: duplicate grid rows along axis {axis}", field=field, value=axis)
    u[-1] = 1.0
    out: np.ndarray = u
    return out


def _as_grid(grid: ArrayLike, field: str) -> np.ndarray:
    g = np.asarray(grid, dtype=float)
    if g.ndim != 3 or g.shape[2] != 3:
        raise GeometryError(f"{field} must be a (nu, nv, 3) grid", field=field, value=list(g.shape))
    as_points(g.reshape(-1, 3), field, dims=(3,))
    return g


def interpolate_surface(
    grid: ArrayLike, degree_u: int = 3, degree_v: int = 3, *, tolerance: Tolerance = DEFAULT_TOLERANCE,
    field: str = "grid",
) -> NurbsSurface:
    """Global surface interpolation (A9.4) through a (nu, nv, 3) grid of points in mm."""
    pu, pv = as_degree(degree_u, "degree_u"), as_degree(degree_v, "degree_v")
    g = _as_grid(grid, field)
    nu, nv = g.shape[:2]
    if nu < pu + 1 or nv < pv + 1:
        raise DegenerateGeometryError(
            f"{field}: needs at least {pu + 1} x {pv + 1} points", field=field, value=[nu, nv]
        )
    u = grid_parameters(g, 0, tolerance, field)
    v = grid_parameters(g, 1, tolerance, field)
    tu, tv = averaged_knots(u, pu), averaged_knots(v, pv)
    r = make_interp_spline(u, g.reshape(nu, nv * 3), k=pu, t=tu).c.reshape(nu, nv, 3)
    c = make_interp_spline(v, r.transpose(1, 0, 2).reshape(nv, nu * 3), k=pv, t=tv).c
    return NurbsSurface(pu, pv, tu, tv, c.reshape(nv, nu, 3).transpose(1, 0, 2), None)


class SurfaceFit(NamedTuple):
    """A fitted surface, the parameters (k, 2) used per point and residuals |S(u,v) - P| (k,) mm."""

    surface: NurbsSurface
    params: np.ndarray
    residual: np.ndarray

    @property
    def max_mm(self) -> float:
        return float(self.residual.max())

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residual**2)))


def _row_kron(a: sp.csr_array, b: sp.csr_array) -> sp.csr_array:
    """Row-wise Kronecker product: out[r, i*nb + j] = a[r, i] * b[r, j]."""
    a, b = sp.csr_array(a), sp.csr_array(b)
    ca, cb = np.diff(a.indptr), np.diff(b.indptr)
    rows_a = np.repeat(np.arange(a.shape[0]), ca)
    rep = cb[rows_a]
    ea = np.repeat(np.arange(a.nnz), rep)
    start = np.repeat(np.cumsum(rep) - rep, rep)
    eb = b.indptr[np.repeat(rows_a, rep)] + (np.arange(rep.sum()) - start)
    data = a.data[ea] * b.data[eb]
    cols = a.indices[ea] * b.shape[1] + b.indices[eb]
    return sp.csr_array((data, (np.repeat(rows_a, rep), cols)), shape=(a.shape[0], a.shape[1] * b.shape[1]))


def _second_difference(n: int) -> sp.csr_array:
    return sp.csr_array(sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(max(n - 2, 0), n)))


def grid_knots(params: np.ndarray, n_control: int, degree: int) -> np.ndarray:
    """Clamped knots (n_control + degree + 1,) for a least-squares fit of n_control control
    points to data at params (m,) increasing on [0, 1], degree + 1 <= n_control <= m: the
    averaged knots (Eq. 9.8) of the parameters resampled (linearly in index) to n_control
    values.  At n_control = m they are the interpolation knots.  Unlike Eq. 9.68-9.69
    (:func:`approximation_knots`), whose collocation matrix becomes singular as n_control
    approaches m (condition 1e9 at 47 of 50 points, 1e20 at 200 of 200), they stay well
    conditioned (condition < 20 measured for every n_control <= m <= 200)."""
    resampled = np.interp(np.linspace(0.0, params.size - 1.0, n_control), np.arange(params.size), params)
    return averaged_knots(resampled, degree)


def _solve_net(design: sp.sparray, pts: np.ndarray, n_u: int, n_v: int, smoothing: float,
               field: str) -> np.ndarray:
    """Control net (n_u n_v, 3), u-major, of min |design c - pts|^2 + smoothing-weighted second
    differences of the net: banded normal equations with the longer net direction outermost
    (bandwidth degree * min(n_u, n_v) + degree: 193 MB at a 200 x 200 net)."""
    order = _net_order(n_u, n_v)
    design = sp.csc_array(design)[:, order]
    a = design.T @ design
    if smoothing > 0:
        du = sp.kron(_second_difference(n_u), sp.eye(n_v))
        dv = sp.kron(sp.eye(n_u), _second_difference(n_v))
        pen = sp.csr_array(du.T @ du + dv.T @ dv)[order][:, order]
        scale = (design.multiply(design)).sum() / max(pen.diagonal().sum(), DIVISION_FLOOR)
        a = a + smoothing * scale * pen
        del pen
    rhs = design.T @ pts
    del design
    ab = _banded_upper(a)
    del a  # only the band is kept while LAPACK factors it
    ctrl = np.empty((n_u * n_v, pts.shape[1]))
    ctrl[order] = _solve_banded_spd(ab, rhs, field)
    return ctrl


def fit_surface(
    points: ArrayLike, n_ctrl_u: int, n_ctrl_v: int, degree_u: int = 3, degree_v: int = 3, smoothing: float = 0.0,
    *, bounds: tuple[float, float, float, float] | None = None, tolerance: Tolerance = DEFAULT_TOLERANCE,
    field: str = "points",
) -> SurfaceFit:
    """Penalised least-squares NURBS surface through scattered points (k, 3) or a grid (nu, nv, 3).

    Scattered points are parametrised by x, y over ``bounds`` = (x0, x1, y0, y1) (default
    their bounding box): the part's top as seen from above.  A grid uses averaged chord
    parameters and :func:`grid_knots`.  ``smoothing`` >= 0 weights a second-difference penalty
    on the control net (relative to the data term; 0 = plain least squares).

    Solvers: a grid without smoothing separates by direction (:func:`_solve_tensor_grid`,
    two 1-D banded solves, memory O(grid)); otherwise the (n_ctrl_u n_ctrl_v)-unknown normal
    equations by a banded Cholesky (:func:`_solve_net`).
    """
    pu, pv = as_degree(degree_u, "degree_u"), as_degree(degree_v, "degree_v")
    for name, n, p in (("n_ctrl_u", n_ctrl_u, pu), ("n_ctrl_v", n_ctrl_v, pv)):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < p + 1:
            raise GeometryError(f"{name} must be an integer >= {p + 1}", field=name, value=n)
    if not (isinstance(smoothing, (int, float)) and np.isfinite(smoothing) and smoothing >= 0):
        raise GeometryError("smoothing must be >= 0", field="smoothing", value=smoothing)
    arr = np.asarray(points, dtype=float)
    if arr.ndim == 3:
        g = _as_grid(arr, field)
        for name, n, size in (("n_ctrl_u", n_ctrl_u, g.shape[0]), ("n_ctrl_v", n_ctrl_v, g.shape[1])):
            if n > size:
                raise GeometryError(f"{name} must not exceed the grid size {size}", field=name, value=n)
        u, v = grid_parameters(g, 0, tolerance, field), grid_parameters(g, 1, tolerance, field)
        tu, tv = grid_knots(u, n_ctrl_u, pu), grid_knots(v, n_ctrl_v, pv)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        uv, pts = np.column_stack([uu.ravel(), vv.ravel()]), g.reshape(-1, 3)
    else:
        pts = as_points(arr, field, dims=(3,), min_count=1)
        lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
        x0, x1, y0, y1 = bounds if bounds is not None else (lo[0], hi[0], lo[1], hi[1])
        if not (x1 - x0 > tolerance.dedup_mm and y1 - y0 > tolerance.dedup_mm):
            raise DegenerateGeometryError(f"{field}: the points span no area in x and y", field=field,
                                          value=[x0, x1, y0, y1])
        uv = np.column_stack([(pts[:, 0] - x0) / (x1 - x0), (pts[:, 1] - y0) / (y1 - y0)])
        if uv.min() < -DOMAIN_SLACK_REL or uv.max() > 1 + DOMAIN_SLACK_REL:
            raise GeometryError(f"{field}: points outside the fit region", field="bounds", value=list(bounds or ()))
        uv = np.clip(uv, 0.0, 1.0)
        tu = np.concatenate([np.zeros(pu), np.linspace(0, 1, n_ctrl_u - pu + 1), np.ones(pu)])
        tv = np.concatenate([np.zeros(pv), np.linspace(0, 1, n_ctrl_v - pv + 1), np.ones(pv)])
    if arr.ndim == 3 and smoothing == 0:  # a grid: the fit separates by direction
        ctrl = _solve_tensor_grid(BSpline.design_matrix(u, tu, pu), BSpline.design_matrix(v, tv, pv), g, field)
    else:
        ctrl = _solve_net(_row_kron(BSpline.design_matrix(uv[:, 0], tu, pu), BSpline.design_matrix(uv[:, 1], tv, pv)),
                          pts, n_ctrl_u, n_ctrl_v, smoothing, field)
    surface = NurbsSurface(pu, pv, tu, tv, ctrl.reshape(n_ctrl_u, n_ctrl_v, 3), None)
    residual = np.linalg.norm(surface.evaluate(uv[:, 0], uv[:, 1]) - pts, axis=1)
    return SurfaceFit(surface, uv, residual)


def approximate_surface(
    points: ArrayLike, n_ctrl_u: int, n_ctrl_v: int, degree_u: int = 3, degree_v: int = 3, smoothing: float = 0.0,
    **kwargs: object,
) -> NurbsSurface:
    """The surface of :func:`fit_surface` (same arguments)."""
    return fit_surface(points, n_ctrl_u, n_ctrl_v, degree_u, degree_v, smoothing, **kwargs).surface  # type: ignore[arg-type]
