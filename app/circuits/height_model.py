"""The warp's height model chosen by the probe points: candidates compared by cross-validation.

Candidates (each a :class:`~app.circuits.heightfield.HeightField`, the bicubic the chord bound
is proved against):

* ``grid_bicubic`` (probes on every node of a rectangular grid only): the interpolating
  bicubic spline on the probes' own grid (scipy ``RectBivariateSpline``, s = 0);
* ``clough_tocher``: C1 interpolation on the probes' Delaunay triangles, resampled onto a grid;
* ``polyharmonic``: the polyharmonic spline of order 3 (scipy ``RBFInterpolator``, kernel
  -r^5 with a quadratic polynomial: the smoothest interpolant in its native space), resampled
  onto a grid;
* ``kriging`` (scattered points only): the deviation GP of :mod:`app.probing.deviation_prior`
  (band-limited jinc kernel, the kernel the field reconstruction uses) on the probes' departure
  from their least-squares quadratic, posterior mean resampled onto a grid.  Its wavelength is
  chosen by the GP's exact leave-one-out residuals over a log grid (r_i = (K^-1 dz)_i /
  (K^-1)_ii), its amplitude by maximum likelihood at that wavelength (rms^2 = dz' K1^-1 dz / n,
  K1 the unit kernel), its noise is the probe's repeatability.

``polyharmonic`` and ``kriging`` are candidates up to :data:`KRIGING_MAX_POINTS` points (a fitted
surface's thousands of samples keep the other two).  On a grid kriging is not a candidate:
leaving grid rows out (the only way the grid bicubic can be cross-validated) doubles the
spacing, where a long-wavelength GP predicts best while it is the worst model at the real
spacing (measured on the dome of tests/circuits/test_height_model.py: row-out rms 88-96 um
against the bicubic's 112 um, true error 2.4x the bicubic's).

Choice: on a grid, interior grid rows and columns (every one, or ``_ROW_FOLDS`` evenly spread
on each axis) are left out in turn and predicted by
each candidate from the rest (the bicubic needs a grid); scattered points are left out one by
one (up to ``_LOO_MAX_POINTS``), in 10 folds, or one tenth held out once (above
``_ONE_FOLD_POINTS``).  The candidate with the smallest rms prediction error is used; its rms
and max error are reported as the model's own uncertainty (the chord bound holds against the
model; this is how far the model may be from the part), with kriging's largest posterior sd
over the measured region when kriging is chosen.  The kriging hyperparameters are chosen on
all points and held fixed across the folds (the trend and the posterior are refitted per fold).

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.interpolate import RectBivariateSpline

from app.circuits.heightfield import HeightField, checked_points, height_field_from_points
from app.probing.deviation_prior import DeviationPrior, Sites, fit_posterior, jinc_kernel

__all__ = ["HeightModel", "KRIGING_MAX_POINTS", "height_model_from_points"]

Array = npt.NDArray[np.float64]
#: ``predict(train (n, 3), at (m, 2)) -> (m,)`` mm
Predictor = Callable[[Array, Array], Array]

#: scattered points above this many are cross-validated in 10 folds instead of one by one
_LOO_MAX_POINTS = 30
#: and above this many (a fitted surface's samples) one tenth is held out once
_ONE_FOLD_POINTS = 1000
#: kriging is a candidate up to this many points (one dense factorisation per wavelength tried)
KRIGING_MAX_POINTS = 1000
#: wavelengths tried (log-spaced from 2x the probes' median spacing to 2x the region's diagonal)
KRIGING_WAVELENGTHS = 9
#: the probe's repeatability (1 sigma, mm): the deviation prior's default
PROBE_NOISE_MM = DeviationPrior().sigma_mm
#: points evaluated per block when the kriging mean / sd is resampled (bounds the memory)
_BLOCK = 4096
_GRID_DECIMALS = 6
#: interior grid rows (and columns) left out at most, evenly spread (each fold rebuilds every candidate)
_ROW_FOLDS = 10


class HeightModel(NamedTuple):
    """How a height field was built from probe points: ``kind`` (``grid_bicubic``,
    ``clough_tocher`` or ``kriging``); ``cv`` the cross-validation scheme
    (``leave_one_row_out`` on a grid; ``leave_one_out``, ``10_fold``, ``holdout_10pct`` on
    scattered points); ``cv_rms_mm``, ``cv_max_mm`` the chosen model's prediction errors;
    ``alternatives``: {kind: cv rms mm} of every candidate compared; ``kriging``: the kriging
    candidate's wavelength_mm, amplitude_mm (peak), noise_mm and its exact leave-one-out
    rms_mm / max_mm (None when kriging was not a candidate); ``posterior_sd_max_mm``: the
    chosen kriging model's largest posterior sd over the measured region (None for the others)."""

    kind: str
    cv: str
    cv_rms_mm: float
    cv_max_mm: float
    alternatives: dict[str, float]
    kriging: dict[str, float] | None = None
    posterior_sd_max_mm: float | None = None


# --- kriging --------------------------------------------------------------------------------
def _trend_basis(xy: Array, center: Array, scale: float, quadratic: bool) -> Array:
    u, v = ((xy - center) / scale).T
    cols = [np.ones(len(u)), u, v] + ([u * u, u * v, v * v] if quadratic else [])
    return np.column_stack(cols)


class Kriging:
    """The deviation GP on scattered heights: quadratic least-squares trend (a plane below 12
    points) + the posterior mean of the jinc-kernel GP of the residual.  ``wavelength_mm`` and
    ``rms_mm`` fixed (see :func:`choose_kriging`)."""

    def __init__(self, pts: Array, wavelength_mm: float, rms_mm: float, noise_mm: float = PROBE_NOISE_MM) -> None:
        self.center = pts[:, :2].mean(axis=0)
        self.scale = float(max(np.ptp(pts[:, 0]), np.ptp(pts[:, 1]), 1e-9))
        self.quadratic = len(pts) >= 12
        basis = _trend_basis(pts[:, :2], self.center, self.scale, self.quadratic)
        self.coef = np.linalg.lstsq(basis, pts[:, 2], rcond=None)[0]
        dz = pts[:, 2] - basis @ self.coef
        self.prior = DeviationPrior(amplitude_mm=rms_mm * DeviationPrior.peak_factor, wavelength_mm=wavelength_mm,
                                    placement_xy_mm=0.0, placement_z_mm=0.0, placement_rz_deg=0.0, tilt_rad=0.0,
                                    sigma_mm=noise_mm)
        self.posterior = fit_posterior(self.prior, Sites(pts[:, :2], np.zeros((len(pts), 2))), dz, self.center)

    def __call__(self, xy: Array) -> Array:
        """Height (m,) mm at xy (m, 2)."""
        out = np.empty(len(xy))
        for a in range(0, len(xy), _BLOCK):
            b = xy[a:a + _BLOCK]
            out[a:a + _BLOCK] = (_trend_basis(b, self.center, self.scale, self.quadratic) @ self.coef
                                 + self.posterior.mean(Sites(b, np.zeros((len(b), 2)))))
        return out

    def sd(self, xy: Array) -> Array:
        """Posterior sd (m,) mm at xy (m, 2) (of the GP part; the trend's own uncertainty aside)."""
        return np.concatenate([self.posterior.sd(Sites(b, np.zeros((len(b), 2))))
                               for b in (xy[a:a + _BLOCK] for a in range(0, len(xy), _BLOCK))] or [np.zeros(0)])


def _median_spacing(xy: Array) -> float:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(xy).query(xy, k=2)
    return float(np.median(d[:, 1]))


def choose_kriging(pts: Array, noise_mm: float = PROBE_NOISE_MM) -> tuple[float, float, Array]:
    """(wavelength mm, rms mm, exact leave-one-out residuals (n,) mm) of the kriging model of
    points (n, 3) mm: the wavelength with the smallest LOO rms over a log grid, the rms its
    maximum-likelihood value."""
    xy = pts[:, :2]
    basis = _trend_basis(xy, xy.mean(axis=0), float(max(np.ptp(xy[:, 0]), np.ptp(xy[:, 1]), 1e-9)), len(pts) >= 12)
    dz = pts[:, 2] - basis @ np.linalg.lstsq(basis, pts[:, 2], rcond=None)[0]
    spacing = _median_spacing(xy)
    diagonal = float(np.hypot(np.ptp(xy[:, 0]), np.ptp(xy[:, 1])))
    best: tuple[float, float, float, Array] | None = None
    for wavelength in np.geomspace(2 * spacing, max(2 * diagonal, 4 * spacing), KRIGING_WAVELENGTHS):
        unit = jinc_kernel(xy, xy, float(wavelength))
        rms = max(float(np.std(dz)), noise_mm, 1e-9)
        for _ in range(2):                       # ML scale at this wavelength (the noise ratio depends on it)
            k1 = unit + (noise_mm / rms) ** 2 * np.eye(len(xy)) + 1e-10 * np.eye(len(xy))
            rms = max(math.sqrt(max(float(dz @ np.linalg.solve(k1, dz)) / len(dz), 0.0)), 1e-9)
        q = np.linalg.inv(rms ** 2 * k1)
        resid = (q @ dz) / np.diag(q)
        score = float(np.sqrt(np.mean(resid ** 2)))
        if best is None or score < best[0]:
            best = (score, float(wavelength), rms, resid)
    assert best is not None
    return best[1], best[2], best[3]


class _Polyharmonic:
    """The polyharmonic spline (order 3) through points (n, 3) mm: height (m,) at xy (m, 2)."""

    def __init__(self, pts: Array) -> None:
        from scipy.interpolate import RBFInterpolator

        self.rbf = RBFInterpolator(pts[:, :2], pts[:, 2], kernel="quintic")

    def __call__(self, xy: Array) -> Array:
        return np.concatenate([self.rbf(xy[a:a + _BLOCK]) for a in range(0, len(xy), _BLOCK)] or [np.zeros(0)])


def _polyharmonic_predict(train: Array, at: Array) -> Array:
    return _Polyharmonic(train)(at)


def resampled_field(pts: Array, spacing_mm: float, model: Callable[[Array], Array],
                    sd: Callable[[Array], Array] | None = None) -> tuple[HeightField, float | None]:
    """``model(xy (m, 2)) -> (m,)`` mm on a grid of ``spacing_mm`` over the points' bounding box
    (their convex hull the measured region), and the largest ``sd`` (mm) at the grid nodes inside
    the hull (None without ``sd``)."""
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    nx = max(4, int(np.ceil((hi[0] - lo[0]) / spacing_mm)) + 1)
    ny = max(4, int(np.ceil((hi[1] - lo[1]) / spacing_mm)) + 1)
    x, y = np.linspace(lo[0], hi[0], nx), np.linspace(lo[1], hi[1], ny)
    X, Y = np.meshgrid(x, y, indexing="ij")
    nodes = np.column_stack([X.ravel(), Y.ravel()])
    field = HeightField(x, y, model(nodes).reshape(X.shape), hull_points=pts[:, :2])
    if sd is None:
        return field, None
    inside = nodes[field.inside(nodes[:, 0], nodes[:, 1])]
    return field, float(sd(inside).max(initial=0.0))


# --- cross-validation -----------------------------------------------------------------------
def _as_grid(pts: Array) -> tuple[Array, Array, Array] | None:
    """(x (nx,), y (ny,), z (nx, ny)) when the points are every node of a rectangular grid, else None."""
    xr, yr = np.round(pts[:, 0], _GRID_DECIMALS), np.round(pts[:, 1], _GRID_DECIMALS)
    ux, ix = np.unique(xr, return_inverse=True)
    uy, iy = np.unique(yr, return_inverse=True)
    if len(ux) * len(uy) != len(pts) or len(ux) < 4 or len(uy) < 4:
        return None
    z = np.full((len(ux), len(uy)), np.nan)
    z[ix, iy] = pts[:, 2]
    if not np.isfinite(z).all():
        return None
    return ux, uy, z


def _ct_predict(train: Array, at: Array) -> Array:
    """Clough-Tocher of ``train`` (n, 3) at ``at`` (m, 2), the nearest point outside its hull."""
    from scipy.interpolate import CloughTocher2DInterpolator, NearestNDInterpolator

    z: Array = CloughTocher2DInterpolator(train[:, :2], train[:, 2])(at)
    missing = ~np.isfinite(z)
    if missing.any():
        z[missing] = NearestNDInterpolator(train[:, :2], train[:, 2])(at[missing])
    return z


def _grid_row_cv(x: Array, y: Array, z: Array, predictors: dict[str, Predictor]) -> dict[str, Array]:
    """Prediction errors (mm) of the bicubic on the grid and of every scattered-point predictor
    when each interior grid row (x) and column (y) is left out in turn: {kind: errors}."""
    errors: dict[str, list[Array]] = {"grid_bicubic": [], **{k: [] for k in predictors}}
    X, Y = np.meshgrid(x, y, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), z.ravel()])
    for axis, coords in ((0, x), (1, y)):
        if len(coords) < 5:
            continue                            # a bicubic needs 4 rows after one is left out
        for k in np.unique(np.linspace(1, len(coords) - 2, min(len(coords) - 2, _ROW_FOLDS)).round().astype(int)):
            keep = np.arange(len(coords)) != k
            if axis == 0:
                spline = RectBivariateSpline(x[keep], y, z[keep], kx=3, ky=3, s=0)
                truth, at = z[k], np.column_stack([np.full(len(y), x[k]), y])
            else:
                spline = RectBivariateSpline(x, y[keep], z[:, keep], kx=3, ky=3, s=0)
                truth, at = z[:, k], np.column_stack([x, np.full(len(x), y[k])])
            errors["grid_bicubic"].append(spline.ev(at[:, 0], at[:, 1]) - truth)
            held = np.isclose(pts[:, axis], coords[k])
            for kind, predict in predictors.items():
                errors[kind].append(predict(pts[~held], at) - truth)
    return {kind: np.concatenate(e) if e else np.zeros(0) for kind, e in errors.items()}


def _scattered_cv(pts: Array, predictors: dict[str, Predictor]) -> tuple[str, dict[str, Array]]:
    """(scheme, {kind: errors mm}) on scattered points: leave-one-out, 10 folds, or one holdout."""
    n = len(pts)
    folds = n if n <= _LOO_MAX_POINTS else 10
    order = np.random.default_rng(0).permutation(n)
    errors: dict[str, list[Array]] = {k: [] for k in predictors}
    for f in range(folds if n <= _ONE_FOLD_POINTS else 1):
        held = order[f::folds]
        keep = np.ones(n, bool)
        keep[held] = False
        if keep.sum() < 4:
            continue
        for kind, predict in predictors.items():
            errors[kind].append(predict(pts[keep], pts[held, :2]) - pts[held, 2])
    scheme = "leave_one_out" if folds == n else ("10_fold" if n <= _ONE_FOLD_POINTS else "holdout_10pct")
    return scheme, {k: np.concatenate(e) if e else np.zeros(0) for k, e in errors.items()}


def _summary(errors: Array) -> tuple[float, float]:
    if not len(errors):
        return math.nan, math.nan
    return float(np.sqrt(np.mean(errors ** 2))), float(np.abs(errors).max())


def height_model_from_points(points: npt.ArrayLike, spacing_mm: float = 1.0,
                             noise_mm: float = PROBE_NOISE_MM) -> tuple[HeightField, HeightModel]:
    """The height field the probe points (n, 3) mm support best, and how it was chosen (module
    doc); ``spacing_mm``: the resampling grid of the scattered-point models; ``noise_mm``: the
    probe's repeatability (1 sigma) the kriging model assumes."""
    pts = checked_points(points)
    predictors: dict[str, Predictor] = {"clough_tocher": _ct_predict}
    kriging_info: dict[str, float] | None = None
    wavelength = rms = math.nan
    grid = _as_grid(pts)
    if 6 <= len(pts) <= KRIGING_MAX_POINTS:
        predictors["polyharmonic"] = _polyharmonic_predict
    if grid is None and 6 <= len(pts) <= KRIGING_MAX_POINTS:
        wavelength, rms, loo = choose_kriging(pts, noise_mm)
        kriging_info = {"wavelength_mm": wavelength, "amplitude_mm": rms * DeviationPrior.peak_factor,
                        "noise_mm": noise_mm, "loo_rms_mm": float(np.sqrt(np.mean(loo ** 2))),
                        "loo_max_mm": float(np.abs(loo).max())}

        def krige(train: Array, at: Array) -> Array:
            return Kriging(train, wavelength, rms, noise_mm)(at)
        predictors["kriging"] = krige
    errors: dict[str, Array] = {}
    if grid is not None:
        errors = _grid_row_cv(*grid, predictors)
        scheme = "leave_one_row_out"
    if not errors or not len(errors["grid_bicubic"]):
        scheme, errors = _scattered_cv(pts, predictors)
    scores = {kind: _summary(e) for kind, e in errors.items()}
    finite = {k: v for k, v in scores.items() if math.isfinite(v[0])}
    kind = min(finite, key=lambda k: finite[k][0]) if finite else "clough_tocher"
    rms_cv, max_cv = scores.get(kind, (math.nan, math.nan))
    alternatives = {k: v[0] for k, v in scores.items()}
    sd_max = None
    if kind == "grid_bicubic" and grid is not None:
        field = HeightField(*grid, hull_points=pts[:, :2])
    elif kind == "kriging":
        model = Kriging(pts, wavelength, rms, noise_mm)
        field, sd_max = resampled_field(pts, spacing_mm, model, model.sd)
    elif kind == "polyharmonic":
        field, _ = resampled_field(pts, spacing_mm, _Polyharmonic(pts))
    else:
        field = height_field_from_points(pts, spacing_mm)
    return field, HeightModel(kind, scheme, rms_cv, max_cv, alternatives, kriging_info, sd_max)
