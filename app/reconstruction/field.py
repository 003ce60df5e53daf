"""One fitted field per probe run, evaluated along every trace (reconstruction ``"field"``).

The stations of a field plan (:func:`app.probing.field.plan_field`) measure the deviation
dz = measured z - nominal z at their xy.  :func:`fit_field` conditions the deviation prior
(band-limited machining error + rigid placement) on all of them ONCE: one factorisation of
the stations' covariance, alpha = K^-1 dz.  :func:`trace_reconstruction` then evaluates the
posterior mean along one trace (K(trace points, stations) @ alpha: no refit), so a board of
any number of traces costs one fit plus one matrix-vector product per trace.

Outliers (chip, dust, probe bounce) are found by the exact leave-one-out residuals of the
GP, r_i = alpha_i / Q_ii with Q = K^-1 (each station predicted from all the others), sd_i =
1 / sqrt(Q_ii): among the stations whose |r_i| exceeds ``max(k_sigma * sd_i, floor)`` the
least consistent one (largest |r_i| / sd_i) is dropped and the fit repeated (a spike also
disturbs its neighbours' residuals, but less in units of their sd).

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.linalg import cho_factor, cho_solve

from app.geometry.fitting import interpolate_curve
from app.geometry.tolerance import COVARIANCE_JITTER_REL
from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import (
    DeviationPosterior,
    DeviationPrior,
    Sites,
    jinc_kernel,
    path_sites,
    placement_basis,
    prior_covariance,
)
from app.reconstruction.heights import FieldHeight
from app.reconstruction.preprocess import CleanPoints, ReconstructionError
from app.reconstruction.reconstruct import Reconstruction, ReconstructParams

MAX_OFFSET_MM = 0.5
OUTLIER_K_SIGMA = 6.0
OUTLIER_FLOOR_MM = 0.03
MAX_OUTLIER_SHARE = 0.1
CURVE_STEP_MM = 0.1  # stations of the result NURBS (cubic through the real trace)
DENSE_STEP_MM = 0.05  # the placement part's spline step: the CAD slopes' features are ~0.25 mm wide
COARSE_PER_WAVELENGTH = 60  # the machining part's spline step lambda / 60: cubic error ~1e-5 of it


@dataclass(frozen=True, eq=False)
class FieldFit:
    """The fitted field of one probe run.

    posterior: the deviation posterior (mean/sd at any sites).  stations: Sites (n,) of
    every planned station; dz (n,) measured deviation mm; kept (n,) bool; outliers: indices
    of rejected stations; trace (n,) / s_mm (n,) the station's trace and arc length (-1 /
    NaN off the traces).
    """

    posterior: DeviationPosterior
    stations: Sites
    dz: np.ndarray
    kept: np.ndarray
    outliers: tuple[int, ...]
    trace: np.ndarray
    s_mm: np.ndarray

    def deviation(self, sites: Sites) -> np.ndarray:
        """Posterior mean deviation (m,) mm at ``sites``."""
        return self.posterior.mean(sites)

    def machining(self, xy: np.ndarray) -> np.ndarray:
        """The machining-error part (m,) mm of the posterior mean at xy (m, 2) (band-limited:
        smooth on the scale of lambda)."""
        prior = self.posterior.prior
        out: np.ndarray = prior.rms_mm ** 2 * jinc_kernel(xy, self.posterior.probes.xy,
                                                          prior.wavelength_mm) @ self.posterior.alpha
        return out

    def placement(self, sites: Sites) -> np.ndarray:
        """The placement part (m,) mm of the posterior mean at ``sites``: B(sites) theta, with
        theta (6,) the posterior mean of (dz, dx, dy, rz, tx, ty); deviation = machining + this."""
        prior = self.posterior.prior
        probes = placement_basis(self.posterior.probes, self.posterior.center)
        theta = prior.basis_sd ** 2 * (probes.T @ self.posterior.alpha)
        out: np.ndarray = placement_basis(sites, self.posterior.center) @ theta
        return out


def field_gradient(fit: FieldFit, sites: Sites, step_mm: float = 0.05,
                   slope_at: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Top-view gradient (m, 2) of the fitted deviation at ``sites`` by central differences
    over ``step_mm``.  ``slope_at(xy (k, 2)) -> (k, 2)``: the nominal slope at the shifted
    points (the placement part of the deviation follows it: -grad h . displacement); None
    holds each site's own slope (exact for the machining part and on planar stretches)."""
    out = np.zeros((len(sites.xy), 2))
    for axis in range(2):
        shift = np.zeros(2)
        shift[axis] = step_mm
        ends = []
        for xy in (sites.xy + shift, sites.xy - shift):
            grad = sites.grad if slope_at is None else np.asarray(slope_at(xy), dtype=float)
            ends.append(fit.deviation(Sites(xy, grad)))
        out[:, axis] = (ends[0] - ends[1]) / (2 * step_mm)
    return out


def _loo(k: np.ndarray, dz: np.ndarray, jitter: float) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-out residuals (n,) mm and their sd (n,) mm of a GP with covariance k."""
    q = np.linalg.inv(k + jitter * np.eye(len(k)))
    alpha = q @ dz
    d = np.diag(q)
    return alpha / d, 1.0 / np.sqrt(d)


def fit_field(prior: DeviationPrior, stations: Sites, nominal_z: np.ndarray, measured: np.ndarray,
              center: np.ndarray, trace: np.ndarray | None = None, s_mm: np.ndarray | None = None,
              field: str = "points") -> FieldFit:
    """Fit the field once.  stations: the planned Sites (n,); nominal_z (n,) mm their
    nominal heights; measured (n, 3) mm the probe results in station order (each within
    MAX_OFFSET_MM of its station in xy); center (2,) mm the plan's placement centre.
    Raises ReconstructionError (422) naming ``field`` for bad input."""
    pts = np.asarray(measured, dtype=float)
    n = len(stations.xy)
    if pts.shape != (n, 3):
        raise ReconstructionError(f"{field}: expected {n} measured points [x, y, z] (one per station), "
                                  f"got shape {list(pts.shape)}", field=field, value=list(pts.shape))
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ReconstructionError(f"{field}.{i} is not finite", field=f"{field}.{i}", value=pts[i].tolist())
    off = np.linalg.norm(pts[:, :2] - stations.xy, axis=1)
    if off.max() > MAX_OFFSET_MM:
        i = int(np.argmax(off))
        raise ReconstructionError(f"{field}.{i} lies {off[i]:.3f} mm from its station (limit {MAX_OFFSET_MM} mm)",
                                  field=f"{field}.{i}", value=pts[i].tolist())
    if n < 2:
        raise ReconstructionError("a field needs at least 2 stations", field=field, value=n)
    dz = pts[:, 2] - np.asarray(nominal_z, dtype=float)
    jitter = max(prior.sigma_mm ** 2, COVARIANCE_JITTER_REL * prior.rms_mm ** 2)
    k_all = prior_covariance(prior, stations, stations, center)
    kept = np.ones(n, dtype=bool)
    outliers: list[int] = []
    while len(outliers) < MAX_OUTLIER_SHARE * n:
        idx = np.flatnonzero(kept)
        resid, sd = _loo(k_all[np.ix_(idx, idx)], dz[idx], jitter)
        over = np.abs(resid) > np.maximum(OUTLIER_K_SIGMA * sd, OUTLIER_FLOOR_MM)
        if not over.any():
            break
        worst = int(np.argmax(np.where(over, np.abs(resid) / sd, -1.0)))  # the least consistent
        kept[idx[worst]] = False
        outliers.append(int(idx[worst]))
    idx = np.flatnonzero(kept)
    factor = cho_factor(k_all[np.ix_(idx, idx)] + jitter * np.eye(len(idx)), lower=True)
    posterior = DeviationPosterior(prior, np.asarray(center, dtype=float), stations.take(idx),
                                   cho_solve(factor, dz[idx]), factor)
    return FieldFit(posterior, stations, dz, kept, tuple(sorted(outliers)),
                    np.full(n, -1) if trace is None else np.asarray(trace, dtype=int),
                    np.full(n, np.nan) if s_mm is None else np.asarray(s_mm, dtype=float))


def trace_reconstruction(fit: FieldFit, path: TracePolyline, trace_index: int,
                         params: ReconstructParams | None = None) -> Reconstruction:
    """The real trace ``path`` (the plan's trace number ``trace_index``) from the fitted
    field: nominal + posterior mean (evaluated every DENSE_STEP_MM and interpolated by a cubic
    spline), valid over the whole trace (the plan's posterior sd says how well).  The result
    curve interpolates the real trace every CURVE_STEP_MM (compensation reads the heights,
    not the curve).  samples: this trace's own kept stations [s, dz]; max_mm / rms_mm: of
    the reconstructed deviation along the trace (every ``profile_step_mm``)."""
    params = params or ReconstructParams()
    # the posterior mean once along the trace, then cubic splines (compensation queries
    # heights thousands of times per trace): the band-limited machining part every
    # lambda / COARSE_PER_WAVELENGTH, the placement part (it follows the CAD slope) every DENSE_STEP_MM
    coarse = fit.posterior.prior.wavelength_mm / COARSE_PER_WAVELENGTH
    s_coarse = np.linspace(0.0, path.length_mm, max(4, int(math.ceil(path.length_mm / coarse)) + 1))
    s_dense = np.linspace(0.0, path.length_mm, max(4, int(math.ceil(path.length_mm / DENSE_STEP_MM)) + 1))
    machining = make_interp_spline(s_coarse, fit.machining(path.at(s_coarse)[:, :2]), k=3)
    placement = make_interp_spline(s_dense, fit.placement(path_sites(path, s_dense)), k=3)

    height = FieldHeight(path, machining, placement)
    own = np.flatnonzero((fit.trace == trace_index) & fit.kept)
    own = own[np.argsort(fit.s_mm[own])]
    s_own = fit.s_mm[own]
    pts = path.at(s_own) if len(own) else np.zeros((0, 3))
    pts[:, 2] += fit.dz[own]
    clean = CleanPoints(pts, s_own, fit.dz[own], tuple(int(i) for i in np.flatnonzero(
        (fit.trace == trace_index) & ~fit.kept)), 0)
    s_prof = np.linspace(0.0, path.length_mm, max(2, int(math.ceil(path.length_mm / params.profile_step_mm)) + 1))
    dev = height(s_prof) - path.z_at(s_prof)
    s_curve = np.linspace(0.0, path.length_mm, max(params.degree + 1,
                                                   int(math.ceil(path.length_mm / CURVE_STEP_MM)) + 1))
    curve_pts = path.at(s_curve)
    curve_pts[:, 2] = height(s_curve)
    return Reconstruction(method="field", curve=interpolate_curve(curve_pts, params.degree), clean=clean,
                          samples=np.stack([s_own, fit.dz[own]], axis=1), max_mm=float(np.abs(dev).max()),
                          rms_mm=float(np.sqrt(np.mean(dev ** 2))), nominal=path, _height_s=height,
                          span_mm=(0.0, float(path.length_mm)))


def fit_bytes(fit: FieldFit) -> int:
    """Memory held by a fit (bytes): its factor and station arrays."""
    low = fit.posterior.factor[0]
    return int(low.nbytes + fit.stations.xy.nbytes * 4 + fit.dz.nbytes * 4)
