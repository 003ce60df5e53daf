"""A measured surface as a height field z = h(x, y) with a PROVED curvature bound.

h is a bicubic spline interpolating z on a rectangular grid (scipy ``RectBivariateSpline``,
s = 0).  Its second derivatives are splines too, and a B-spline lies within the range of its
active coefficients on each knot cell (convex hull property), so per cell

    |d^T H d| <= max(Mxx, Myy) + Mxy      for any unit direction d (|2 d_x d_y| <= 1),

with Mxx, Myy, Mxy the largest |coefficient| of h_xx, h_yy, h_xy active on the cell.  Along a
straight top-view segment of length L the height's departure from its chord is then at most
L^2 / 8 * max over the cells the segment's bounding box touches (2-D sparse-table maxima).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.interpolate import RectBivariateSpline
from scipy.spatial import Delaunay

from app.circuits.errors import WarpError
from app.geometry.tolerance import LENGTH_EPS_MM

#: scipy Delaunay.find_simplex tolerance (barycentric coordinates): a point this far
#: outside the hull's edge still counts as inside
_HULL_BARYCENTRIC_TOL = 1e-9

__all__ = ["HeightField", "Inside", "Region", "checked_points", "height_field_from_points", "points_region"]

#: ``inside(x (n,), y (n,)) -> (n,) bool``: whether points (mm) lie in a measured region
Inside = Callable[[npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.NDArray[np.bool_]]


class Region(NamedTuple):
    """A measured region: its membership test and its bounds (x0, x1, y0, y1) mm."""

    inside: Inside
    bounds: tuple[float, float, float, float]


def _cell_bound(spline: RectBivariateSpline, nu: int, nv: int, cells_x: npt.NDArray[np.float64],
                cells_y: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Max |coefficient| of a derivative spline active on each knot cell (cx, cy)."""
    from numpy.lib.stride_tricks import sliding_window_view

    d = spline.partial_derivative(nu, nv)
    tx, ty, c = d.tck
    kx, ky = d.degrees
    coef = np.abs(np.asarray(c)).reshape(len(tx) - kx - 1, len(ty) - ky - 1)
    window = sliding_window_view(coef, (kx + 1, ky + 1)).max(axis=(-2, -1))   # [j - k] -> span j
    # cell [x0, next knot) lies in span j of the derived knots where tx[j] <= x0 < tx[j + 1]
    jx = np.clip(np.searchsorted(tx, cells_x, side="right") - 1, kx, len(tx) - kx - 2) - kx
    jy = np.clip(np.searchsorted(ty, cells_y, side="right") - 1, ky, len(ty) - ky - 2) - ky
    bound: npt.NDArray[np.float64] = window[np.ix_(jx, jy)]
    return bound


@dataclass
class HeightField:
    """z (nx, ny) mm on the grid x (nx,), y (ny,) (increasing); optional ``hull`` (k, 2) points
    whose convex hull is the measured region (defaults to the grid's rectangle)."""

    x: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    z: npt.NDArray[np.float64]
    hull_points: npt.NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        self.x, self.y, self.z = (np.asarray(a, float) for a in (self.x, self.y, self.z))
        if self.z.shape != (len(self.x), len(self.y)) or len(self.x) < 4 or len(self.y) < 4:
            raise WarpError("a height field needs z of shape (len(x), len(y)) with at least 4 x 4 points",
                            field="surface", value=list(self.z.shape))
        self.spline = RectBivariateSpline(self.x, self.y, self.z, kx=3, ky=3, s=0)
        tx, ty = self.spline.get_knots()
        self._tx, self._ty = tx, ty
        lo_x, lo_y = tx[:-1], ty[:-1]
        mxx = _cell_bound(self.spline, 2, 0, lo_x, lo_y)
        myy = _cell_bound(self.spline, 0, 2, lo_x, lo_y)
        mxy = _cell_bound(self.spline, 1, 1, lo_x, lo_y)
        self._table = [np.maximum(mxx, myy) + mxy]
        while min(self._table[-1].shape) > 1:         # 2-D sparse table of maxima over 2^k x 2^k windows
            t = self._table[-1]
            h = 1 << (len(self._table) - 1)
            nxt = np.maximum(np.maximum(t[:-h, :-h], t[h:, :-h]), np.maximum(t[:-h, h:], t[h:, h:])) \
                if t.shape[0] > h and t.shape[1] > h else None
            if nxt is None or nxt.size == 0:
                break
            self._table.append(nxt)
        self._hull = Delaunay(self.hull_points) if self.hull_points is not None else None

    def height(self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """h at points (n,) mm (clamped to the grid outside it)."""
        xc = np.clip(x, self.x[0], self.x[-1])
        yc = np.clip(y, self.y[0], self.y[-1])
        h: npt.NDArray[np.float64] = self.spline.ev(xc, yc)  # scipy: untyped
        return h

    def inside(self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64],
               slack: float = LENGTH_EPS_MM) -> npt.NDArray[np.bool_]:
        """True where (x, y) is in the measured region."""
        ok: npt.NDArray[np.bool_] = ((x >= self.x[0] - slack) & (x <= self.x[-1] + slack)
                   & (y >= self.y[0] - slack) & (y <= self.y[-1] + slack))
        if self._hull is not None:
            ok &= self._hull.find_simplex(np.column_stack([x, y]), tol=_HULL_BARYCENTRIC_TOL) >= 0
        return ok

    def curvature_bound(self, x0: npt.NDArray[np.float64], y0: npt.NDArray[np.float64], x1: npt.NDArray[np.float64],
                        y1: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Bound (n,) 1/mm (proved for this spline) on |d^2 h / ds^2| along each segment (x0, y0) -> (x1, y1)."""
        ncx, ncy = self._table[0].shape
        ix0 = np.clip(np.searchsorted(self._tx, np.minimum(x0, x1), side="right") - 1, 0, ncx - 1)
        ix1 = np.clip(np.searchsorted(self._tx, np.maximum(x0, x1), side="right") - 1, 0, ncx - 1)
        iy0 = np.clip(np.searchsorted(self._ty, np.minimum(y0, y1), side="right") - 1, 0, ncy - 1)
        iy1 = np.clip(np.searchsorted(self._ty, np.maximum(y0, y1), side="right") - 1, 0, ncy - 1)
        span = np.maximum(ix1 - ix0 + 1, iy1 - iy0 + 1)
        level = np.minimum(np.floor(np.log2(span)).astype(int), len(self._table) - 1)
        out = np.zeros(len(ix0))
        for k in np.unique(level):
            sel = level == k
            t = self._table[k]
            w = 1 << k
            a0, a1 = ix0[sel], np.maximum(ix1[sel] - w + 1, ix0[sel])
            b0, b1 = iy0[sel], np.maximum(iy1[sel] - w + 1, iy0[sel])
            a0, a1 = np.minimum(a0, t.shape[0] - 1), np.minimum(a1, t.shape[0] - 1)
            b0, b1 = np.minimum(b0, t.shape[1] - 1), np.minimum(b1, t.shape[1] - 1)
            out[sel] = np.maximum.reduce([t[a0, b0], t[a1, b0], t[a0, b1], t[a1, b1]])
        uncovered = span > 2 * (1 << level)          # wider than the coarsest window pair: whole grid
        out[uncovered] = self._table[0].max()
        return out


def checked_points(points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """``points`` as (n, 3) finite mm, at least 4 spanning an area (else WarpError)."""
    pts = np.asarray(points, float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 4 or not np.isfinite(pts).all():
        raise WarpError("a surface needs at least 4 finite (x, y, z) points", field="surface",
                        value=list(pts.shape))
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    if (hi - lo).min() <= 0:
        raise WarpError("the surface points span no area", field="surface", value=[lo.tolist(), hi.tolist()])
    return pts


def points_region(points: npt.ArrayLike) -> Region:
    """The measured region of scattered surface points (n, 3) mm, as :func:`height_field_from_points`
    defines it (their convex hull), without building the field: :class:`Region` (inside(x (m,), y (m,))
    -> (m,) bool, bounds (x0, x1, y0, y1) mm)."""
    pts = checked_points(points)
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    hull = Delaunay(pts[:, :2])

    def inside(x: npt.NDArray[np.float64], y: npt.NDArray[np.float64],
               slack: float = LENGTH_EPS_MM) -> npt.NDArray[np.bool_]:
        """True where (x, y) mm is in the points' convex hull."""
        box = (x >= lo[0] - slack) & (x <= hi[0] + slack) & (y >= lo[1] - slack) & (y <= hi[1] + slack)
        # scipy: untyped
        ok: npt.NDArray[np.bool_] = box & (hull.find_simplex(np.column_stack([x, y]), tol=_HULL_BARYCENTRIC_TOL) >= 0)
        return ok

    return Region(inside, (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])))


def height_field_from_points(points: npt.ArrayLike, spacing_mm: float = 1.0) -> HeightField:
    """A height field from scattered surface points (n, 3) mm (probe touches, a fitted surface's
    samples): C1 Clough-Tocher interpolation onto a grid of ``spacing_mm`` over their bounding
    box; the measured region is their convex hull (grid nodes outside it take the nearest value)."""
    from scipy.interpolate import CloughTocher2DInterpolator, NearestNDInterpolator

    pts = checked_points(points)
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    nx = max(4, int(np.ceil((hi[0] - lo[0]) / spacing_mm)) + 1)
    ny = max(4, int(np.ceil((hi[1] - lo[1]) / spacing_mm)) + 1)
    x, y = np.linspace(lo[0], hi[0], nx), np.linspace(lo[1], hi[1], ny)
    X, Y = np.meshgrid(x, y, indexing="ij")
    z = CloughTocher2DInterpolator(pts[:, :2], pts[:, 2])(X, Y)
    missing = ~np.isfinite(z)
    if missing.any():
        z[missing] = NearestNDInterpolator(pts[:, :2], pts[:, 2])(X[missing], Y[missing])
    return HeightField(x, y, z, hull_points=pts[:, :2])
