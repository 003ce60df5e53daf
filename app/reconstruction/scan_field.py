"""The deviation field from tens of thousands of scan samples: an inducing-point solve.

A dense GP on n samples costs O(n^3) (30,000 samples: a 7 GB matrix).  The field's prior
(:mod:`app.probing.deviation_prior`: a band-limited machining error + 6 placement terms)
has few degrees of freedom over a part, so it is represented exactly enough by

    f(x) = rms^2 jinc(x, U) a + B(x) theta

with U a lattice of inducing points at ``spacing_mm`` (default lambda / 3: finer than the
band limit's Nyquist spacing lambda / 2) kept within lambda / 2 of a sample, a ~ weights
with prior precision K_UU (the deterministic-training-conditional approximation) and theta
the placement coefficients with their own prior (exact, not through U).  With the features
Phi(x) = [K(x, U), B(x)] the posterior of the weights has precision
``P = diag(K_UU + jitter, S^-1) + Phi' Phi / sigma^2`` and mean ``P^-1 Phi' y / sigma^2``:
Phi' Phi is accumulated in chunks of samples, so memory is O(m^2) and time O(n m^2) for
m inducing points.  The posterior sd adds the Nystrom residual rms^2 - k K_UU^-1 k' to
Phi P^-1 Phi'.  Outliers: samples whose residual exceeds ``OUTLIER_K`` robust sd (MAD) are
dropped and the fit repeated once.

The result is a :class:`app.reconstruction.field.FieldFit` (its posterior and its
machining / placement parts overridden), so trace reconstruction, the field check and the
verification points use it as they use a touch field.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve, cholesky, solve_triangular
from scipy.spatial import cKDTree

from app.geometry.tolerance import COVARIANCE_JITTER_REL
from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import (
    DeviationPosterior,
    DeviationPrior,
    Sites,
    jinc_kernel,
    path_sites,
    placement_basis,
    prior_variance,
)
from app.reconstruction.field import FieldFit
from app.reconstruction.field_trust import FieldCheck, Verification, joint_coverage
from app.reconstruction.preprocess import ReconstructionError

CHUNK = 4096
OUTLIER_K = 6.0
OUTLIER_FLOOR_MM = 0.005
INDUCING_PER_WAVELENGTH = 3.0
MAX_INDUCING = 6000
INDUCING_JITTER_REL = 1e-6  # K_UU + this x rms^2: the band-limited kernel's lattice Gram is near-singular


def inducing_lattice(xy: np.ndarray, wavelength_mm: float, spacing_mm: float | None = None) -> np.ndarray:
    """Lattice points (m, 2) at ``spacing_mm`` (default lambda / 3) within lambda / 2 of a
    sample of xy (n, 2)."""
    step = spacing_mm or wavelength_mm / INDUCING_PER_WAVELENGTH
    lo, hi = xy.min(axis=0) - step, xy.max(axis=0) + step
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + step, step), np.arange(lo[1], hi[1] + step, step))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    near = cKDTree(xy).query(grid, distance_upper_bound=wavelength_mm / 2)[0] < np.inf
    out: np.ndarray = grid[near]
    if len(out) > MAX_INDUCING:
        raise ReconstructionError(f"{len(out)} inducing points (limit {MAX_INDUCING}): the scanned area is too "
                                  "large for the wavelength", field="deviation_wavelength_mm", value=wavelength_mm)
    return out


@dataclass(frozen=True, eq=False)
class SparsePosterior(DeviationPosterior):
    """The inducing-point posterior: probes = the inducing Sites U, alpha (m,) the machining
    weights (mean = rms^2 jinc(x, U) alpha), theta (6,) the placement coefficients; solved
    whitened: K_UU + jitter = L L' (``low``), weights v = [L' alpha, theta / sd] ~ N(0, I),
    factor = Cholesky of the weights' posterior precision I + Psi' Psi / sigma^2."""

    theta: np.ndarray = field(default_factory=lambda: np.zeros(6))
    low: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def whitened(self, sites: Sites) -> tuple[np.ndarray, np.ndarray]:
        """Psi (q, m + 6) at ``sites`` and the machining kernel rows K(x, U) (q, m)."""
        prior = self.prior
        kj = prior.rms_mm ** 2 * jinc_kernel(sites.xy, self.probes.xy, prior.wavelength_mm)
        psi = solve_triangular(self.low, kj.T, lower=True).T
        return np.concatenate([psi, placement_basis(sites, self.center) * prior.basis_sd], axis=1), kj

    def mean(self, sites: Sites) -> np.ndarray:
        prior = self.prior
        kj = prior.rms_mm ** 2 * jinc_kernel(sites.xy, self.probes.xy, prior.wavelength_mm)
        out: np.ndarray = kj @ self.alpha + placement_basis(sites, self.center) @ self.theta
        return out

    def sd(self, sites: Sites) -> np.ndarray:
        psi, _ = self.whitened(sites)
        var = np.sum(psi.T * cho_solve(self.factor, psi.T), axis=0)
        m = len(self.alpha)
        nystrom = self.prior.rms_mm ** 2 - np.sum(psi[:, :m] ** 2, axis=1)
        out: np.ndarray = np.sqrt(np.maximum(var + np.maximum(nystrom, 0.0), 0.0))
        return out


@dataclass(frozen=True, eq=False)
class ScanFieldFit(FieldFit):
    """A field fitted to scan samples (stations: the samples; trace -1, s NaN); its
    machining part is the inherited rms^2 jinc(x, U) alpha, its placement part B(x) theta."""

    def placement(self, sites: Sites) -> np.ndarray:
        post = self.posterior
        assert isinstance(post, SparsePosterior)
        out: np.ndarray = placement_basis(sites, post.center) @ post.theta
        return out


def _solve(prior: DeviationPrior, samples: Sites, dz: np.ndarray, center: np.ndarray, inducing: Sites,
           low: np.ndarray, noise_mm: np.ndarray | None = None) -> SparsePosterior:
    """The posterior; ``noise_mm`` (n,) each sample's noise sd (None: ``prior.sigma_mm`` for all)."""
    m = len(inducing.xy)
    floor = COVARIANCE_JITTER_REL * prior.rms_mm ** 2
    sigma2 = np.maximum(np.full(len(dz), prior.sigma_mm ** 2) if noise_mm is None else
                        np.asarray(noise_mm, dtype=float) ** 2, floor)
    p = np.eye(m + 6)
    rhs = np.zeros(m + 6)
    probe = SparsePosterior(prior, center, inducing, np.zeros(m), (p, True), low=low)
    for start in range(0, len(dz), CHUNK):
        stop = min(start + CHUNK, len(dz))
        psi, _ = probe.whitened(samples.take(np.arange(start, stop)))
        w = 1.0 / sigma2[start:stop]
        p += psi.T @ (psi * w[:, None])
        rhs += psi.T @ (dz[start:stop] * w)
    factor = cho_factor(p, lower=True)
    v = cho_solve(factor, rhs)
    alpha = solve_triangular(low.T, v[:m], lower=False)
    return SparsePosterior(prior, center, inducing, alpha, factor, theta=v[m:] * prior.basis_sd, low=low)


def _inducing(prior: DeviationPrior, xy_samples: np.ndarray, slope_at: Callable[[np.ndarray], np.ndarray] | None,
              spacing_mm: float | None) -> tuple[Sites, np.ndarray]:
    xy = inducing_lattice(xy_samples, prior.wavelength_mm, spacing_mm)
    grad = np.zeros_like(xy) if slope_at is None else np.asarray(slope_at(xy), dtype=float)
    kuu = prior.rms_mm ** 2 * jinc_kernel(xy, xy, prior.wavelength_mm)
    low = cholesky(kuu + INDUCING_JITTER_REL * prior.rms_mm ** 2 * np.eye(len(xy)), lower=True)
    return Sites(xy, grad), low


def fit_scan_field(prior: DeviationPrior, samples: Sites, dz: np.ndarray, center: np.ndarray,
                   slope_at: Callable[[np.ndarray], np.ndarray] | None = None,
                   spacing_mm: float | None = None, noise_mm: np.ndarray | None = None) -> ScanFieldFit:
    """The field of scan samples (n,) measuring deviations dz (n,) mm (finite: drop the
    sensor's dropouts first).  ``slope_at(xy (m, 2)) -> (m, 2)``: the nominal slope at the
    inducing points (None: zero; only the placement basis reads it, and theta is exact).
    ``noise_mm`` (n,): each sample's noise sd (probe touches among sensor samples; None:
    ``prior.sigma_mm`` for all); outliers are judged on residuals in units of it."""
    dz = np.asarray(dz, dtype=float)
    n = len(dz)
    if samples.xy.shape != (n, 2) or n < 8:
        raise ReconstructionError("a scan field needs at least 8 samples, one deviation each", field="samples",
                                  value=[list(samples.xy.shape), n])
    if not np.isfinite(dz).all():
        raise ReconstructionError("scan deviations must be finite (drop the dropouts first)", field="samples")
    noise = None if noise_mm is None else np.asarray(noise_mm, dtype=float)
    relative = np.ones(n) if noise is None else noise / max(prior.sigma_mm, 1e-12)
    inducing, low = _inducing(prior, samples.xy, slope_at, spacing_mm)
    kept = np.ones(n, dtype=bool)
    post = _solve(prior, samples, dz, center, inducing, low, noise)
    resid = (dz - np.concatenate([post.mean(samples.take(np.arange(s, min(s + CHUNK, n))))
                                  for s in range(0, n, CHUNK)])) / relative
    scale = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    over = np.abs(resid) > max(OUTLIER_K * scale, OUTLIER_FLOOR_MM)
    if over.any():
        kept = ~over
        idx = np.flatnonzero(kept)
        post = _solve(prior, samples.take(idx), dz[idx], center, inducing, low, None if noise is None else noise[idx])
    return ScanFieldFit(post, samples, dz, kept, tuple(int(i) for i in np.flatnonzero(~kept)),
                        np.full(n, -1), np.full(n, math.nan))


def gap_sites(fit: FieldFit, paths: Sequence[TracePolyline], coverage: float, target_mm: float,
              count: int) -> tuple[Sites, np.ndarray]:
    """Up to ``count`` trace points (Sites, their trace indices (k,)) where the fitted field is
    too uncertain for the target (coverage x sd > target: where the sensor dropped out on a
    steep flank or a dark spot), largest sd first, at least lambda / 4 apart: where a probe
    touch fills the gap."""
    wavelength = fit.posterior.prior.wavelength_mm
    sites = [path_sites(p, np.linspace(0.0, p.length_mm, max(2, int(np.ceil(16 * p.length_mm / wavelength)) + 1)))
             for p in paths]
    owner = np.concatenate([np.full(len(s.xy), i) for i, s in enumerate(sites)])
    every = Sites(np.concatenate([s.xy for s in sites]), np.concatenate([s.grad for s in sites]))
    sd = fit.posterior.sd(every)
    wanted = np.flatnonzero(coverage * sd > target_mm)
    picked: list[int] = []
    for i in wanted[np.argsort(sd[wanted])[::-1]]:
        if len(picked) >= count:
            break
        if not picked or np.min(np.linalg.norm(every.xy[picked] - every.xy[i], axis=1)) >= wavelength / 4:
            picked.append(int(i))
    idx = np.array(picked, dtype=int)
    return every.take(idx), owner[idx]


def posterior_sd(prior: DeviationPrior, sites: Sites, center: np.ndarray) -> np.ndarray:
    """Prior sd (q,) mm at ``sites`` (the scale a scan plan's predicted sd is judged on)."""
    out: np.ndarray = np.sqrt(prior_variance(prior, sites, center))
    return out


def predicted_sd(prior: DeviationPrior, samples: Sites, center: np.ndarray, query: Sites,
                 slope_at: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Posterior sd (q,) mm at ``query`` if the field were measured at ``samples`` (n,) with
    noise ``prior.sigma_mm`` (it does not depend on the values: a plan's bound, in advance)."""
    inducing, low = _inducing(prior, samples.xy, slope_at, None)
    post = _solve(prior, samples, np.zeros(len(samples.xy)), center, inducing, low)
    return np.concatenate([post.sd(query.take(np.arange(s, min(s + CHUNK, len(query.xy)))))
                           for s in range(0, len(query.xy), CHUNK)])


def verify_touches(fit: FieldFit, sites: Sites, measured_mm: np.ndarray, trace: np.ndarray, coverage: float,
                   probe_sigma_mm: float) -> Verification:
    """Verification touches (k,) against a scan field: as :func:`app.reconstruction.field_trust.verify`
    (each point's limit :func:`joint_coverage` x its predictive sd), with the predictive sd of
    a TOUCH (the field's posterior sd and the probe's noise, not the averaged scan samples'
    noise the field was fitted with)."""
    predicted = fit.deviation(sites)
    sd = np.sqrt(fit.posterior.sd(sites) ** 2 + probe_sigma_mm ** 2)
    return Verification(sites.xy, np.asarray(trace, dtype=int), np.asarray(measured_mm, dtype=float), predicted,
                        sd, joint_coverage(coverage, len(sd)) * sd, coverage * probe_sigma_mm)


@dataclass(frozen=True)
class ScanFieldCheck(FieldCheck):
    """The checked field of a scan: the fit of the samples, judged at probe touches.  A
    touch reads its own noise (``touch_sigma_mm``, the probe's) on top of the field's error,
    not the averaged samples' noise the field was fitted with: the noise allowance is
    coverage x the probe's sd."""

    touch_sigma_mm: float = 0.0

    @property
    def noise_allowance_mm(self) -> float:
        return float(self.coverage * self.touch_sigma_mm)
