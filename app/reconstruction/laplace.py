"""The Laplace approximation's sd of parameters at a minimum (pure: numpy).

Units: those of the parameters (the learning's are log amplitude, log wavelength, log sigma).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def laplace_sd(objective: Callable[[np.ndarray], float], theta: np.ndarray, at: tuple[str, ...],
               h: float) -> np.ndarray:
    """sd (p,) of the parameters ``theta`` (p,) at the minimum of ``objective`` (a negative log
    density) from its inverse Hessian there, by central differences of step ``h``, over the
    parameters not on a bound (``at`` (p,): "lower" / "upper" / ""); NaN for those on one, and
    where the Hessian is singular or its inverse has no positive variance."""
    free = [i for i in range(len(theta)) if not at[i]]
    out = np.full(len(theta), np.nan)
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
    diag = np.diag(cov)
    out[free] = np.where(diag > 0, np.sqrt(np.abs(diag)), np.nan)
    return out
