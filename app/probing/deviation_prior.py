"""A Gaussian-process prior for the deviation of a real part from its CAD nominal.

The deviation dz (real height - nominal height, mm) seen at a top-view point p = (x, y) is
modelled as the sum of

* a **machining error** field e(x, y): zero mean, stationary and isotropic in the plane,
  band-limited to wavelengths >= ``wavelength_mm`` (flat disk spectrum), so its covariance
  is the 2-D "jinc" kernel ``rms^2 * 2 J1(k r) / (k r)``, k = 2 pi / wavelength,
  r = |p - p'| (mm).  rms = ``amplitude_mm / peak_factor`` (the amplitude is a peak);
* a **rigid placement** error of the part (offset dx, dy, dz, rotation rz, tilt tx, ty):
  to first order it changes the height by
  ``dz + tx (x - cx) + ty (y - cy) - grad h . (dx - rz (y - cy), dy + rz (x - cx))``
  where grad h (2,) is the nominal's slope (known from CAD, here from the surface normals)
  and c the centre of the probed region.  Each coefficient gets an independent zero-mean
  Gaussian prior with its tolerance as standard deviation.

Both parts are linear in Gaussian unknowns, so the deviation is one Gaussian process whose
covariance is the kernel plus ``B diag(tol^2) B'`` over the placement basis B (m, 6).  The
posterior (kriging) mean is the reconstruction; the posterior standard deviation does not
depend on the measured values, which is what lets a planner choose stations in advance
(a sequential, after-each-touch planner would choose the same stations).

Pure: numpy/scipy only.  Units: mm, rad inside; ``placement_rz_deg`` at the boundary.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.ndimage import gaussian_filter1d

from app.domain.checks import require_non_negative, require_positive
from app.domain.errors import InvalidInput
from app.geometry.tolerance import COVARIANCE_JITTER_REL, DEGENERATE_LENGTH_MM
from app.geometry.traces import TracePolyline
from app.probing.bessel_table import jinc


class PriorError(InvalidInput):
    """Deviation-prior parameters that cannot be used."""


@dataclass(frozen=True)
class DeviationPrior:
    """What is expected of the real part (mm unless named otherwise).

    amplitude_mm: peak machining error; wavelength_mm: its shortest wavelength.
    peak_factor: peak / rms of the machining error (3: a Gaussian field's peak over a part).
    placement_xy_mm, placement_z_mm, placement_rz_deg, tilt_rad: 1-sigma placement errors.
    sigma_mm: probe repeatability (1 sigma).
    """

    amplitude_mm: float = 0.2
    wavelength_mm: float = 20.0
    peak_factor: float = 3.0
    placement_xy_mm: float = 0.1
    placement_z_mm: float = 0.05
    placement_rz_deg: float = 0.2
    tilt_rad: float = 0.001
    sigma_mm: float = 0.001

    def __post_init__(self) -> None:
        require_positive(self, ("amplitude_mm", "wavelength_mm", "peak_factor"), PriorError)
        require_non_negative(self, ("placement_xy_mm", "placement_z_mm", "placement_rz_deg",
                                    "tilt_rad", "sigma_mm"), PriorError)

    @property
    def rms_mm(self) -> float:
        return self.amplitude_mm / self.peak_factor

    @property
    def basis_sd(self) -> np.ndarray:
        """(6,) prior sd of (dz, dx, dy, rz, tx, ty) in mm, mm, mm, rad, rad, rad."""
        t = self.placement_xy_mm
        return np.array([self.placement_z_mm, t, t, math.radians(self.placement_rz_deg),
                         self.tilt_rad, self.tilt_rad])


@dataclass(frozen=True, eq=False)
class Sites:
    """Top-view points where the deviation is measured or wanted.

    xy: (m, 2) mm.  grad: (m, 2) nominal slope (dh/dx, dh/dy) there (dimensionless).
    """

    xy: np.ndarray
    grad: np.ndarray

    def take(self, idx: np.ndarray) -> Sites:
        return Sites(self.xy[idx], self.grad[idx])


SLOPE_SMOOTHING_MM = 0.25   # Gaussian sigma (arc length) of the slope the placement term uses
SLOPE_SAMPLE_MM = 0.02
JINC_BLOCK_ELEMENTS = 2 ** 16   # elements of the kernel made at once (jinc_kernel's temporaries: 512 KiB each)
_SMOOTH_SLOPES: weakref.WeakKeyDictionary[TracePolyline, BSpline] = weakref.WeakKeyDictionary()


def raw_path_gradient(path: TracePolyline, s: np.ndarray) -> np.ndarray:
    """Nominal slope (m, 2) at arc lengths ``s`` (m,) as the polyline states it: from the
    normals when the path has them (n = (-hx, -hy, 1)/|.|), else only its along-trace part
    dz/ds_xy * tangent_xy.  Piecewise: it jumps wherever a faceted nominal changes face."""
    s = np.asarray(s, dtype=float)
    n = path.normals_at(s)
    if n is not None:
        nz = np.where(np.abs(n[:, 2]) > 1e-6, n[:, 2], 1e-6)
        return np.stack([-n[:, 0] / nz, -n[:, 1] / nz], axis=1)
    d = np.diff(path.points, axis=0)
    dxy = np.linalg.norm(d[:, :2], axis=1)
    seg = np.clip(np.searchsorted(path.s, s, side="right") - 1, 0, len(d) - 1)
    safe = np.where(dxy[seg] > DEGENERATE_LENGTH_MM, dxy[seg], 1.0)
    slope = np.where(dxy[seg] > DEGENERATE_LENGTH_MM, d[seg, 2] / safe, 0.0)
    return slope[:, None] * d[seg, :2] / safe[:, None]


def path_gradient(path: TracePolyline, s: np.ndarray) -> np.ndarray:
    """Smoothed nominal slope (m, 2) at arc lengths ``s`` (m,): :func:`raw_path_gradient`
    sampled every SLOPE_SAMPLE_MM, Gaussian-filtered along the trace (sigma
    SLOPE_SMOOTHING_MM) and interpolated by a cubic spline (cached per path).

    The placement term of the deviation is ``-grad h . displacement``: with a faceted
    nominal the stated slope jumps at every face edge (by ~0.05 on a 0.15 mm mesh), which
    would put steps of several um into a reconstructed real surface that is smooth.  The
    real surface's slope is what a sub-mm displacement sees, so it is averaged over a few
    tenths of a mm; on a smooth (analytic) nominal the filter changes it by ~1e-4.
    """
    s = np.clip(np.asarray(s, dtype=float), 0.0, path.length_mm)
    spline = _SMOOTH_SLOPES.get(path)
    if spline is None:
        count = max(4, int(math.ceil(path.length_mm / SLOPE_SAMPLE_MM)) + 1)
        grid = np.linspace(0.0, path.length_mm, count)
        step = grid[1] - grid[0]
        sigma = SLOPE_SMOOTHING_MM / step
        raw = raw_path_gradient(path, grid)
        pad = min(len(grid) - 1, int(math.ceil(4 * sigma)))
        # point reflection at both ends keeps a linear trend unbiased up to the ends
        padded = np.concatenate([2 * raw[:1] - raw[pad:0:-1], raw,
                                 2 * raw[-1:] - raw[-2:-pad - 2:-1]])
        smooth = gaussian_filter1d(padded, sigma, axis=0, mode="nearest")[pad:pad + len(grid)]
        spline = make_interp_spline(grid, smooth, k=3)
        _SMOOTH_SLOPES[path] = spline
    out: np.ndarray = spline(s)
    return out


def path_sites(path: TracePolyline, s: np.ndarray) -> Sites:
    """Sites on the nominal at arc lengths ``s`` (m,) mm."""
    s = np.asarray(s, dtype=float)
    return Sites(path.at(s)[:, :2], path_gradient(path, s))


_CENTERS: weakref.WeakKeyDictionary[TracePolyline, np.ndarray] = weakref.WeakKeyDictionary()


def path_center(path: TracePolyline) -> np.ndarray:
    """Rotation/tilt centre (2,) mm of a trace: mean top-view point, even in arc length (65
    samples; kept per path, as its smoothed slope is: a board's centre is asked for by every
    plan of it).  A copy: the kept one is not the caller's to change."""
    out = _CENTERS.get(path)
    if out is None:
        out = path.at(np.linspace(0.0, path.length_mm, 65))[:, :2].mean(axis=0)
        _CENTERS[path] = out
    return out.copy()


def placement_basis(sites: Sites, center: np.ndarray) -> np.ndarray:
    """(m, 6) first-order height change per unit (dz, dx, dy, rz, tx, ty) at ``sites``."""
    x = sites.xy[:, 0] - center[0]
    y = sites.xy[:, 1] - center[1]
    hx, hy = sites.grad[:, 0], sites.grad[:, 1]
    return np.stack([np.ones(len(x)), -hx, -hy, hx * y - hy * x, x, y], axis=1)


def jinc_kernel(a: np.ndarray, b: np.ndarray, wavelength_mm: float,
                block_elements: int = JINC_BLOCK_ELEMENTS) -> np.ndarray:
    """Unit-variance band-limited isotropic kernel (m, k) between points a (m, 2), b (k, 2) mm:
    jinc(x) = 2 J1(x) / x, x = 2 pi |a - b| / wavelength, from its table
    (:func:`app.probing.bessel_table.jinc`: within 1e-14 of scipy's j1).

    Made ``block_elements // k`` rows at a time (at least one) into the result, the
    distances' temporaries two reused (rows, k) buffers: besides the (m, k) result it holds
    ~2 x ``block_elements`` float64 (and the table's few temporaries of a block), not three
    more (m, k) arrays (on a board's round, ~500 stations x ~8000 samples: 32 MB each).
    Elementwise: the same numbers for any block."""
    m, k = len(a), len(b)
    out = np.empty((m, k))
    rows = max(1, min(m, block_elements // max(k, 1)))
    dx, dy = np.empty((rows, k)), np.empty((rows, k))
    scale = 2.0 * math.pi / wavelength_mm
    for lo in range(0, m, rows):
        hi = min(lo + rows, m)
        x, y = dx[:hi - lo], dy[:hi - lo]
        np.subtract(a[lo:hi, None, 0], b[None, :, 0], out=x)
        np.subtract(a[lo:hi, None, 1], b[None, :, 1], out=y)
        x *= x
        y *= y
        x += y
        np.sqrt(x, out=x)
        x *= scale
        jinc(x, out=out[lo:hi])
    return out


def prior_covariance(prior: DeviationPrior, a: Sites, b: Sites,
                     center: np.ndarray, jinc: np.ndarray | None = None, *, spend_jinc: bool = False) -> np.ndarray:
    """Prior covariance (m, k) mm^2 of the deviation between sites a and b; ``jinc``:
    ``jinc_kernel(a.xy, b.xy, prior.wavelength_mm)`` (m, k) when the caller has it, and
    with ``spend_jinc`` its array becomes the result (written over: one (m, k) array in
    all, not three, while it is made).  The same numbers either way."""
    sd = prior.basis_sd
    ba = placement_basis(a, center) * sd
    bb = placement_basis(b, center) * sd
    k = jinc_kernel(a.xy, b.xy, prior.wavelength_mm) if jinc is None else jinc
    out: np.ndarray = np.multiply(k, prior.rms_mm ** 2, out=k if jinc is None or spend_jinc else None)
    out += ba @ bb.T
    return out


def prior_variance(prior: DeviationPrior, sites: Sites, center: np.ndarray) -> np.ndarray:
    """Prior variance (m,) mm^2 of the deviation at ``sites`` (the covariance's diagonal)."""
    out: np.ndarray = prior.rms_mm ** 2 + np.sum((placement_basis(sites, center) * prior.basis_sd) ** 2, axis=1)
    return out


def _factor(k: np.ndarray, sigma_mm: float, scale: float) -> tuple[np.ndarray, bool]:
    jitter = max(sigma_mm ** 2, COVARIANCE_JITTER_REL * scale)
    factor: tuple[np.ndarray, bool] = cho_factor(k + jitter * np.eye(len(k)), lower=True)
    return factor


def _explained_variance(factor: tuple[np.ndarray, bool], k: np.ndarray) -> np.ndarray:
    """k' K^-1 k per column of ``k`` (m, q) with K = L L' given by its Cholesky ``factor``
    (m, m): |L^-1 k|^2, one triangular solve (q,) mm^2."""
    c, lower = factor
    w = solve_triangular(c, k, lower=lower, trans=0 if lower else 1, check_finite=False)
    out: np.ndarray = np.einsum("ij,ij->j", w, w)
    return out


@dataclass(frozen=True, eq=False)
class DeviationPosterior:
    """The deviation given measurements: mean and sd at any sites.

    prior, center (2,) mm, probes: the measured Sites, alpha (m,) = K^-1 dz.
    """

    prior: DeviationPrior
    center: np.ndarray
    probes: Sites
    alpha: np.ndarray
    factor: tuple[np.ndarray, bool]

    def mean(self, sites: Sites) -> np.ndarray:
        """Posterior mean deviation (q,) mm at ``sites``."""
        out: np.ndarray = prior_covariance(self.prior, sites, self.probes, self.center) @ self.alpha
        return out

    def sd(self, sites: Sites) -> np.ndarray:
        """Posterior standard deviation (q,) mm at ``sites``: prior variance - |L^-1 k|^2 with
        K = L L' the probes' factor (one triangular solve per site, not the two of K^-1 k)."""
        kq = prior_covariance(self.prior, sites, self.probes, self.center)
        prior_var = prior_variance(self.prior, sites, self.center)
        v = prior_var - _explained_variance(self.factor, kq.T)
        out: np.ndarray = np.sqrt(np.maximum(v, 0.0))
        return out


def fit_posterior(prior: DeviationPrior, probes: Sites, dz: np.ndarray,
                  center: np.ndarray | None = None) -> DeviationPosterior:
    """Condition the prior on deviations dz (m,) mm measured at ``probes`` (+ N(0, sigma^2))."""
    c = probes.xy.mean(axis=0) if center is None else np.asarray(center, dtype=float)
    k = prior_covariance(prior, probes, probes, c)
    factor = _factor(k, prior.sigma_mm, prior.rms_mm ** 2)
    alpha = cho_solve(factor, np.asarray(dz, dtype=float))
    return DeviationPosterior(prior, c, probes, alpha, factor)


def max_posterior_sd(cov: np.ndarray, prior_var: np.ndarray, chosen: np.ndarray,
                     targets: np.ndarray, sigma_mm: float) -> float:
    """Largest posterior sd (mm) over ``targets`` (indices) with probes at ``chosen``
    (indices), all into one precomputed prior covariance ``cov`` (N, N), ``prior_var`` (N,)."""
    kc = cov[np.ix_(chosen, chosen)]
    factor = _factor(kc, sigma_mm, float(prior_var.max()))
    kq = cov[np.ix_(chosen, targets)]
    v = prior_var[targets] - _explained_variance(factor, kq)
    return float(np.sqrt(max(float(v.max()), 0.0)))
