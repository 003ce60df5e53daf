"""Preprocessing of measured points as in the patent (step 1b).

1. bad-point removal: each point is compared with a least-squares cubic B-spline height
   surface (net by GCV, leave-one-out residuals; above 2,000 points one surface per
   k-d-tree neighbourhood tile of 600 points, so memory stays bounded); points whose residual exceeds ``k_sigma`` robust
   standard deviations (1.4826 MAD), and at least ``min_mm``, are removed and the surface refitted
   (dominant ones first, until stable).  A local quadratic through the nearest neighbours was tried first: its
   model error on steep, strongly curved parts (a cylinder's flanks) exceeded 10 um and
   flagged good points;
2. densification ("surface interpolation"): holes are filled from a least-squares
   B-spline height surface of the valid points (thin-plate interpolation when they are
   few; a thin-plate fill copied noise into refilled points), and a grid can be refined
   by an integer factor (interpolating bicubic spline);
3. smoothing along both grid directions (separable): moving average, five-point cubic
   smoothing (least-squares cubic through 5 neighbours; end points with the one-sided
   formulas), or a smoothing spline (scipy's ``make_smoothing_spline``, lambda by GCV).
Degenerate point sets (too few distinct (x, y) positions, positions on one line, an
(x, y) position measured twice where one height per position is needed) raise
:class:`SurfaceFitError` naming the field, never a bare numpy ``LinAlgError``.
Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import (
    BSpline,
    RBFInterpolator,
    RectBivariateSpline,
    make_smoothing_spline,
)

from app.geometry.errors import GeometryError
from app.geometry.fitting import fit_surface as lsq_surface
from app.geometry.tolerance import DEFAULT_TOLERANCE, DEGENERATE_LENGTH_MM, DIVISION_FLOOR
from app.reconstruction.surface_fit.errors import SurfaceFitError
from app.reconstruction.surface_fit.grid import HeightGrid
from app.reconstruction.surface_fit.tiles import neighbourhood_tiles

__all__ = ["BadPointResult", "PointSpread", "check_point_spread", "find_bad_points",
           "choose_control_count", "square_shape",
           "fill_holes", "interpolate_heights", "height_surface_values", "densify_grid",
           "moving_average", "five_point_cubic", "spline_smooth", "smooth_grid"]

_MAD_TO_SIGMA = 1.4826
_LINE_REL = 1e-9  # second/first singular value of the centred (x, y) below this: one line
_ROUNDS = 30
# Above TILE_ABOVE points the bad-point test runs per neighbourhood tile of TILE_CORE points
# (a global dense fit needs k * k/3 * 8 bytes: 4 GB at 40,000 points), each tile's net at
# most TILE_MAX_NET per direction (a tile is a small part of the region).
TILE_ABOVE = 2000
TILE_CORE = 600
TILE_MAX_NET = 12
_FILL_NEIGHBOURS = 40

# five-point cubic smoothing (least-squares cubic through 5 consecutive samples)
_FIVE_INTERIOR = np.array([-3.0, 12.0, 17.0, 12.0, -3.0]) / 35.0
_FIVE_FIRST = np.array([69.0, 4.0, -6.0, 4.0, -1.0]) / 70.0
_FIVE_SECOND = np.array([2.0, 27.0, 12.0, -8.0, 2.0]) / 35.0


@dataclass(frozen=True)
class BadPointResult:
    """bad: (k,) bool mask of removed points; residual_mm: (k,) deleted (leave-one-out)
    residuals of the last round; threshold_mm: the cut used."""

    bad: np.ndarray
    residual_mm: np.ndarray
    threshold_mm: float


@dataclass(frozen=True)
class PointSpread:
    """distinct: number of distinct (x, y) positions (closer than ``same_mm`` counts as
    the same); repeats: points beyond the first at an already counted position."""

    distinct: int
    repeats: int


def check_point_spread(points: np.ndarray, needed: int, *, field: str,
                       same_mm: float = DEFAULT_TOLERANCE.dedup_mm,
                       unique: bool = False) -> PointSpread:
    """Check that points (k, 3) (or (k, 2)) have at least ``needed`` distinct (x, y)
    positions spanning an area and, with ``unique``, no position measured twice.

    Raises SurfaceFitError(field=field) naming what is wrong: the count, the line the
    positions lie on, or the number of repeats.
    """
    xy = np.asarray(points, dtype=float)[:, :2]
    keys = np.unique(np.round(xy / same_mm), axis=0) if xy.size else np.zeros((0, 2))
    distinct, repeats = int(keys.shape[0]), int(xy.shape[0] - keys.shape[0])
    if distinct < needed:
        raise SurfaceFitError(f"{distinct} distinct (x, y) positions among {xy.shape[0]} "
                              f"points; at least {needed} are needed", field=field,
                              value={"distinct": distinct, "needed": needed})
    centred = xy - xy.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] <= _LINE_REL * max(sv[0], DIVISION_FLOOR):
        raise SurfaceFitError("the points lie on one line in (x, y): they span no area to "
                              "fit a surface over", field=field,
                              value={"first": xy[0], "last": xy[-1]})
    if unique and repeats:
        raise SurfaceFitError(f"{repeats} points repeat an (x, y) position already measured; "
                              "resampling onto a grid needs one height per position",
                              field=field, value={"repeats": repeats})
    return PointSpread(distinct=distinct, repeats=repeats)


def _solve_failed(exc: np.linalg.LinAlgError, what: str, field: str,
                  n_points: int) -> SurfaceFitError:
    return SurfaceFitError(f"{what} is singular for these points (badly spread or "
                           f"repeated positions): {exc}", field=field, value=n_points)


def _gcv_score(residual: np.ndarray, n_coef: int) -> float:
    n = residual.size
    return float(n * np.sum(residual**2) / max(n - n_coef, 1) ** 2)


def choose_control_count(data: np.ndarray, degree: int, penalty: float,
                         shape: tuple[int, int]) -> tuple[int, int]:
    """Control net size minimising GCV = N RSS / (N - p)^2 over nets of the data's aspect
    (p <= N / 3).  data: (nx, ny, 3) grid or (k, 3) points; shape: (nx, ny) or (s, s)."""
    n_points = data.shape[0] * (data.shape[1] if data.ndim == 3 else 1)
    best, best_score = (degree + 1, degree + 1), np.inf
    aspect = shape[1] / shape[0]
    for m in range(degree + 1, max(shape) + 1):
        mu = min(m, shape[0]) if aspect >= 1 else m
        mv = max(degree + 1, min(shape[1], int(round(mu * aspect))))
        if mu * mv > n_points / 3:
            break
        res = lsq_surface(data, mu, mv, degree, degree, penalty).residual
        score = _gcv_score(res, mu * mv)
        if score < best_score:
            best, best_score = (mu, mv), score
    return best


def square_shape(n_points: int) -> tuple[int, int]:
    """A square (s, s) with s*s ~ n_points: the GCV search shape for scattered points."""
    s = max(2, int(np.sqrt(n_points)))
    return (s, s)


def _height_design(uv: np.ndarray, size: tuple[int, int], degree: int) -> np.ndarray:
    """Dense tensor-product B-spline design (k, nu*nv) on clamped uniform knots, uv in [0,1]."""
    mats = []
    for col, n in zip(uv.T, size):
        knots = np.concatenate([np.zeros(degree), np.linspace(0, 1, n - degree + 1),
                                np.ones(degree)])
        mats.append(BSpline.design_matrix(np.clip(col, 0, 1), knots, degree).toarray())
    out: np.ndarray = (mats[0][:, :, None] * mats[1][:, None, :]).reshape(uv.shape[0], -1)
    return out


def find_bad_points(points: np.ndarray, *, k_sigma: float = 5.0, min_mm: float = 0.01,
                    degree: int = 3, field: str = "points") -> BadPointResult:
    """Outliers among measured points (k,3) mm.

    A least-squares B-spline height surface z(x, y) (net by GCV) is fitted to the kept
    points.  A point is bad when its studentised residual r / sqrt(1 - leverage) exceeds
    ``k_sigma`` robust sigmas (1.4826 MAD) *and* its deleted residual r / (1 - leverage)
    exceeds ``min_mm`` (leverage-aware, so a corner point neither hides by pulling the fit
    nor is flagged for its larger variance).  Each round removes the dominant outliers
    (>= half the worst statistic) and refits, until nothing changes.
    residual_mm holds the deleted residuals; threshold_mm the sigma cut.
    Raises SurfaceFitError (``field``) for fewer than 2 (degree+1)^2 distinct (x, y)
    positions or positions on one line.
    """
    pts = np.asarray(points, dtype=float)
    check_point_spread(pts, 2 * (degree + 1) ** 2, field=field)
    try:
        if pts.shape[0] > TILE_ABOVE:
            return _find_bad_points_tiled(pts, k_sigma, min_mm, degree)
        return _find_bad_points(pts, k_sigma, min_mm, degree)
    except np.linalg.LinAlgError as exc:
        raise _solve_failed(exc, "the bad-point height fit", field, pts.shape[0]) from None


def _find_bad_points_tiled(pts: np.ndarray, k_sigma: float, min_mm: float,
                           degree: int) -> BadPointResult:
    """The same test per neighbourhood tile (:mod:`.tiles`): memory bounded by the tile,
    time linear in the points.  A tile too degenerate to fit (its points on a line) keeps
    its points.  threshold_mm: the largest cut of any tile."""
    bad = np.zeros(pts.shape[0], dtype=bool)
    deleted, threshold = np.zeros(pts.shape[0]), float(min_mm)
    for tile in neighbourhood_tiles(pts[:, :2], TILE_CORE):
        local = pts[tile.neighbourhood]
        try:
            check_point_spread(local, 2 * (degree + 1) ** 2, field="points")
            result = _find_bad_points(local, k_sigma, min_mm, degree, max_net=TILE_MAX_NET)
        except (SurfaceFitError, np.linalg.LinAlgError):
            continue
        judged = slice(0, tile.core.size)  # the core comes first in the neighbourhood
        bad[tile.core] = result.bad[judged]
        deleted[tile.core] = result.residual_mm[judged]
        threshold = max(threshold, result.threshold_mm)
    return BadPointResult(bad=bad, residual_mm=deleted, threshold_mm=threshold)


def _find_bad_points(pts: np.ndarray, k_sigma: float, min_mm: float,
                     degree: int, max_net: int | None = None) -> BadPointResult:
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    uv = (pts[:, :2] - lo) / np.maximum(hi - lo, DEGENERATE_LENGTH_MM)
    bad = np.zeros(pts.shape[0], dtype=bool)
    deleted, threshold = np.zeros(pts.shape[0]), float(min_mm)
    for _ in range(_ROUNDS):
        kept = ~bad
        shape = square_shape(int(kept.sum()))
        if max_net is not None:
            shape = (min(shape[0], max_net), min(shape[1], max_net))
        size = choose_control_count(pts[kept], degree, 0.0, shape)
        design = _height_design(uv, size, degree)
        q, r = np.linalg.qr(design[kept])
        coef = np.linalg.solve(r, q.T @ pts[kept, 2])
        raw = pts[:, 2] - design @ coef
        one_minus_h = np.ones(pts.shape[0])  # removed points: already out of sample
        one_minus_h[kept] = np.maximum(1.0 - np.sum(q * q, axis=1), 0.01)
        deleted = raw / one_minus_h
        signed = raw / np.sqrt(one_minus_h)
        good = signed[kept]
        sigma = _MAD_TO_SIGMA * float(np.median(np.abs(good - np.median(good))))
        student = np.abs(signed - np.median(good))
        threshold = k_sigma * sigma
        over = (student > threshold) & (np.abs(deleted) > min_mm)
        # remove only the dominant outliers of this round (a big spike drags its
        # neighbours' residuals up until it is gone); re-admit removed points that fit
        worst = student[over & kept].max(initial=0.0)
        new_bad = (bad & over) | (over & kept & (student >= 0.5 * worst))
        if np.array_equal(new_bad, bad):
            break
        bad = new_bad
    return BadPointResult(bad=bad, residual_mm=deleted, threshold_mm=max(threshold, min_mm))


def height_surface_values(points: np.ndarray, query_xy: np.ndarray, degree: int = 3, *,
                          field: str = "points") -> np.ndarray:
    """Heights at query_xy (m,2) of a least-squares B-spline height surface (net by GCV)
    through points (k,3) (query points inside the points' bounding box).
    Raises SurfaceFitError (``field``) when the fit is singular for these points."""
    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    scale = np.maximum(hi - lo, DEGENERATE_LENGTH_MM)
    try:
        size = choose_control_count(points, degree, 0.0, square_shape(points.shape[0]))
        design = _height_design((points[:, :2] - lo) / scale, size, degree)
        coef = np.linalg.lstsq(design, points[:, 2], rcond=None)[0]
    except np.linalg.LinAlgError as exc:
        raise _solve_failed(exc, "the height surface fit", field, points.shape[0]) from None
    except GeometryError as exc:
        raise SurfaceFitError(exc.message, field=field, value=exc.value) from None
    out: np.ndarray = _height_design((query_xy - lo) / scale, size, degree) @ coef
    return out


def fill_holes(grid: HeightGrid, degree: int = 3) -> HeightGrid:
    """Fill NaN heights from the valid ones: the least-squares B-spline height surface
    (net by GCV; noise is not copied into the holes), or, with fewer than 2 (degree+1)^2
    valid points, thin-plate interpolation."""
    holes = np.isnan(grid.z)
    if not holes.any():
        return grid
    pts = grid.points()
    check_point_spread(pts, 3, field="grid.z")
    xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
    z = grid.z.copy()
    query = np.column_stack([xx[holes], yy[holes]])
    if pts.shape[0] >= 2 * (degree + 1) ** 2:
        z[holes] = height_surface_values(pts, query, degree, field="grid.z")
    else:
        z[holes] = interpolate_heights(pts, query, field="grid.z")
    return HeightGrid(grid.x, grid.y, z)


def interpolate_heights(points: np.ndarray, query_xy: np.ndarray, *,
                        field: str = "points") -> np.ndarray:
    """Heights at query_xy (m,2) from measured points (k,3): thin-plate spline plus a cubic
    polynomial on the 40 nearest points (the cubic term keeps extrapolation at grid corners
    tame on curved parts; where the points lie on a cubic curve, such as a circle, and the
    cubic term is undetermined, the linear one is used).  The points need distinct (x, y)
    positions spanning an area;
    otherwise (or when a local system is singular) SurfaceFitError names ``field``."""
    n = points.shape[0]
    check_point_spread(points, 3, field=field, unique=True)
    for degree in ((3, 1) if n >= 20 and _cubic_determined(points) else (1,)):
        try:
            rbf = RBFInterpolator(points[:, :2], points[:, 2], kernel="thin_plate_spline",
                                  degree=degree, neighbors=min(_FILL_NEIGHBOURS, n))
            out: np.ndarray = rbf(query_xy)
            return out
        except np.linalg.LinAlgError as exc:
            failure = exc  # points on a cubic curve (a circle, two lines): retry linear
    raise _solve_failed(failure, "the thin-plate interpolation", field, n) from None


def _cubic_determined(points: np.ndarray) -> bool:
    """True when the (x, y) positions determine a cubic polynomial (its 10 monomials are
    independent on them; not so on a circle, two lines, a conic...)."""
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    xy = xy / max(float(np.abs(xy).max()), DIVISION_FLOOR)
    x, y = xy[:, 0], xy[:, 1]
    monomials = np.column_stack([x**i * y**j for i in range(4) for j in range(4 - i)])
    return bool(np.linalg.matrix_rank(monomials, tol=_LINE_REL ** 0.5) == monomials.shape[1])


def densify_grid(grid: HeightGrid, factor: int) -> HeightGrid:
    """Refine a complete grid: (nx-1)*factor+1 x (ny-1)*factor+1 points on the bicubic
    interpolating spline (factor 1 returns the grid)."""
    if factor == 1:
        return grid
    kx, ky = min(3, grid.x.size - 1), min(3, grid.y.size - 1)
    spline = RectBivariateSpline(grid.x, grid.y, grid.z, kx=kx, ky=ky, s=0)
    x = np.linspace(grid.x[0], grid.x[-1], (grid.x.size - 1) * factor + 1)
    y = np.linspace(grid.y[0], grid.y[-1], (grid.y.size - 1) * factor + 1)
    return HeightGrid(x, y, spline(x, y))


def moving_average(values: np.ndarray, window: int = 3, axis: int = 0) -> np.ndarray:
    """Centred moving average of odd ``window`` along ``axis``; near the ends the window
    shrinks symmetrically (so straight lines are reproduced everywhere)."""
    if window < 1 or window % 2 == 0:
        raise SurfaceFitError("moving-average window must be an odd integer >= 1",
                              field="params.moving_average_window", value=window)
    v = np.moveaxis(np.asarray(values, dtype=float), axis, 0)
    n, half = v.shape[0], window // 2
    out = np.empty_like(v)
    csum = np.concatenate([np.zeros((1,) + v.shape[1:]), np.cumsum(v, axis=0)])
    for i in range(n):
        r = min(half, i, n - 1 - i)
        out[i] = (csum[i + r + 1] - csum[i - r]) / (2 * r + 1)
    return np.moveaxis(out, 0, axis)


def five_point_cubic(values: np.ndarray, axis: int = 0) -> np.ndarray:
    """Five-point cubic smoothing along ``axis`` (needs >= 5 samples); reproduces any
    cubic exactly."""
    v = np.moveaxis(np.asarray(values, dtype=float), axis, 0)
    n = v.shape[0]
    if n < 5:
        raise SurfaceFitError("five-point cubic smoothing needs at least 5 points per line",
                              field="params.smoothing", value=n)
    out = np.empty_like(v)
    w = _FIVE_INTERIOR
    out[2:-2] = (w[0] * v[:-4] + w[1] * v[1:-3] + w[2] * v[2:-2] + w[3] * v[3:-1]
                 + w[4] * v[4:])
    out[0] = np.tensordot(_FIVE_FIRST, v[:5], axes=1)
    out[1] = np.tensordot(_FIVE_SECOND, v[:5], axes=1)
    out[-1] = np.tensordot(_FIVE_FIRST, v[-1:-6:-1], axes=1)
    out[-2] = np.tensordot(_FIVE_SECOND, v[-1:-6:-1], axes=1)
    return np.moveaxis(out, 0, axis)


def spline_smooth(coords: np.ndarray, values: np.ndarray, axis: int = 0,
                  lam: float | None = None) -> np.ndarray:
    """Cubic smoothing spline through values along ``axis`` at ``coords`` (lambda by GCV
    when None), evaluated back at ``coords``."""
    if coords.size < 5:
        raise SurfaceFitError("spline smoothing needs at least 5 points per line",
                              field="params.smoothing", value=int(coords.size))
    out: np.ndarray = make_smoothing_spline(coords, values, lam=lam, axis=axis)(coords)
    return out


def smooth_grid(grid: HeightGrid, method: str, *, window: int = 3, passes: int = 1,
                lam: float | None = None) -> HeightGrid:
    """Apply a smoothing ``method`` ("none", "moving_average", "five_point_cubic",
    "spline") along x then y, ``passes`` times, to a complete grid."""
    z = grid.z
    for _ in range(passes if method != "none" else 0):
        if method == "moving_average":
            z = moving_average(moving_average(z, window, 0), window, 1)
        elif method == "five_point_cubic":
            z = five_point_cubic(five_point_cubic(z, 0), 1)
        elif method == "spline":
            z = spline_smooth(grid.y, spline_smooth(grid.x, z, 0, lam), 1, lam)
        else:
            raise SurfaceFitError("smoothing must be none, moving_average, five_point_cubic "
                                  "or spline", field="params.smoothing", value=method)
    return HeightGrid(grid.x, grid.y, z)
