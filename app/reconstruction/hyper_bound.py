"""The hyperparameters' own uncertainty in a run's bound: the corner, or the joint ellipse.

The run's bound (:mod:`app.reconstruction.field_trust`) is computed under a prior whose
amplitude A and wavelength lambda are estimates (type-II ML from a few dozen touches, with the
Laplace covariance S of (log A, log lambda), :mod:`app.reconstruction.field_learning`).  The
bound grows with A and as lambda shortens.  Two ways to allow for the estimates' uncertainty:

- ``"corner"``: A HYPER_SD of its own sd up and lambda HYPER_SD of its own sd down, each on its
  own (:func:`app.reconstruction.field_trust.cautious_prior`).  It ignores their correlation:
  a longer wavelength with a larger amplitude explains much the same touches (correlations of
  0.8 are common), so that corner lies far outside their joint ellipse.
- ``"ellipse"``: the largest bound over the joint ELLIPSE_SD-sd ellipse of (log A, log lambda),
  {d : d' S^-1 d <= r^2} about the estimate (:func:`ellipse_max`), evaluated at the estimate, at
  the ellipse's point of largest A and at its point of shortest lambda, and at the point where
  the linear approximation of log bound through those three is largest, r S g / sqrt(g' S g)
  (g (2,): that approximation's gradient); every trace's bound is the largest of its bounds at
  those points.  Were log bound linear in (log A, log lambda), the last is its one-sided
  Phi(r) quantile under the Laplace approximation: r = 3 is 99.87 %, the hyperparameters held
  to the confidence the default coverage (3 sd) gives one point.  The linearisation only
  finds the point: the bound there is computed, not extrapolated.  The ellipse lies inside its
  bounding box, the corner at r sd each: for a log bound linear in the log parameters the
  ellipse's value is never above that corner's, and equals it at correlation -1.

Pure: numpy.  Units: the offsets are in log parameters (dimensionless); the bounds are the
caller's (mm).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

ELLIPSE_SD = 3.0   # the ellipse's radius in sd: the one-sided 99.87 % of log bound's linear approximation
METHODS = ("corner", "ellipse")


def log_covariance(log_sd: tuple[float, float], rho: float) -> np.ndarray:
    """Covariance (2, 2) of (log A, log lambda) from their sd (2,) and correlation ``rho``; a
    parameter without an sd (NaN: on a bound) is held fixed (its row and column zero, and so
    is the correlation without a finite ``rho``)."""
    sd = np.array([s if math.isfinite(s) and s > 0 else 0.0 for s in log_sd])
    r = rho if math.isfinite(rho) and sd.all() else 0.0
    r = min(max(r, -1.0), 1.0)
    return np.array([[sd[0] ** 2, r * sd[0] * sd[1]], [r * sd[0] * sd[1], sd[1] ** 2]])


def worst_point(cov: np.ndarray, gradient: np.ndarray, radius: float = ELLIPSE_SD) -> np.ndarray:
    """The offset (2,) on the ellipse d' cov^-1 d = radius^2 where gradient . d is largest:
    radius x cov g / sqrt(g' cov g) (zero where g' cov g is not positive: nothing varies)."""
    g = np.asarray(gradient, dtype=float)
    spread = float(g @ cov @ g)
    if not spread > 0.0:
        return np.zeros(2)
    out: np.ndarray = radius * (cov @ g) / math.sqrt(spread)
    return out


def ellipse_points(cov: np.ndarray, radius: float = ELLIPSE_SD) -> tuple[np.ndarray, np.ndarray]:
    """The ellipse's (cov (2, 2), ``radius`` sd) point of largest log A and its point of
    smallest log lambda, offsets (2,) each."""
    return worst_point(cov, np.array([1.0, 0.0]), radius), worst_point(cov, np.array([0.0, -1.0]), radius)


def ellipse_max(bound_of: Callable[[np.ndarray], np.ndarray], cov: np.ndarray,
                radius: float = ELLIPSE_SD) -> np.ndarray:
    """The bounds (T,) of T traces, each the largest of ``bound_of(d)`` (T,) over the offsets d
    (2,) of (log A, log lambda) the module doc names on the ellipse of ``cov`` (2, 2) at
    ``radius`` sd: the estimate (d = 0), the points of largest A and of shortest lambda, and
    the point where the linear approximation of log max bound through those three is largest
    (left out where they do not determine it: a parameter held fixed, or correlation +-1)."""
    ends = [d for d in ellipse_points(cov, radius) if np.any(d != 0.0)]
    bounds = [np.asarray(bound_of(np.zeros(2)), dtype=float)] + [np.asarray(bound_of(d), dtype=float) for d in ends]
    if len(ends) == 2:
        logs = np.log([float(b.max()) for b in bounds])
        try:
            g = np.linalg.solve(np.array(ends), logs[1:] - logs[0])
        except np.linalg.LinAlgError:
            g = np.full(2, np.nan)
        if np.isfinite(g).all():
            worst = worst_point(cov, g, radius)
            if not any(np.allclose(worst, d, rtol=1e-9, atol=1e-12) for d in ends + [np.zeros(2)]):
                bounds.append(np.asarray(bound_of(worst), dtype=float))
    out: np.ndarray = np.maximum.reduce(bounds)
    return out
