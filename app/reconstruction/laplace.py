"""The Laplace approximation's covariance and sd of parameters at a minimum (pure: numpy).

Units: those of the parameters (the learning's are log amplitude, log wavelength, log sigma).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def laplace_covariance(objective: Callable[[np.ndarray], float], theta: np.ndarray, at: tuple[str, ...],
                       h: float) -> np.ndarray:
    """Covariance (p, p) of the parameters ``theta`` (p,) at the minimum of ``objective`` (a
    negative log density): the inverse of its Hessian there, by central differences of step
    ``h``, over the parameters not on a bound (``at`` (p,): "lower" / "upper" / ""); the rows
    and columns of those on one are NaN (held fixed), and all of it is NaN where the Hessian
    of the free parameters is singular."""
    free = [i for i in range(len(theta)) if not at[i]]
    out = np.full((len(theta), len(theta)), np.nan)
    if not free:
        return out
    m = len(free)
    hess = np.zeros((m, m))
    f0 = objective(theta)
    for a, i in enumerate(free):
        for b, j in enumerate(free[a:], a):
            def f(di: float, dj: float, i: int = i, j: int = j) -> float:
                t = theta.copy()
                t[i] += di
                t[j] += dj
                return float(objective(t))
            if i == j:
                hess[a, a] = (f(h, 0) - 2 * f0 + f(-h, 0)) / h ** 2
            else:
                hess[a, b] = hess[b, a] = (f(h, h) - f(h, -h) - f(-h, h) + f(-h, -h)) / (4 * h * h)
    try:
        cov = np.linalg.inv(hess)
    except np.linalg.LinAlgError:
        return out
    out[np.ix_(free, free)] = cov
    return out


def covariance_sd(cov: np.ndarray) -> np.ndarray:
    """sd (p,) from a covariance (p, p) of :func:`laplace_covariance`: NaN where the variance
    is NaN or not positive."""
    diag = np.diag(cov)
    with np.errstate(invalid="ignore"):
        return np.where(diag > 0, np.sqrt(np.abs(diag)), np.nan)


def correlation(cov: np.ndarray, i: int, j: int) -> float:
    """The correlation of parameters ``i`` and ``j`` of a covariance (p, p); NaN where either
    has no positive variance."""
    sd = covariance_sd(cov)
    return float(cov[i, j] / (sd[i] * sd[j])) if np.isfinite(sd[i]) and np.isfinite(sd[j]) else float("nan")
