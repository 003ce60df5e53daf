"""Number of measurement points, the height-compensation paper's eq. 1, implemented exactly as printed.

    N = 1/2 * [ (1 + K) / (1 - K) * Z_gamma ]^2  =  1/2 * [ (2 / (1 - K) - 1) * Z_gamma ]^2

K is the process capability coefficient, Z_gamma the gamma-quantile of the standard
normal distribution.

Documented inconsistency (kept on purpose, see SEEDS.md S1): the paper's text says N
falls as the process gets better (larger K).  The printed formula does the opposite for
0 < K < 1: (1+K)/(1-K) grows without bound as K -> 1 (K = 1 is a pole), so a *better*
process needs *more* points.  Only for K > 1 (where the factor is negative, and squared)
does N fall with K, towards Z_gamma^2 / 2.  We expose the formula as is, with both inputs,
and report the monotonic direction in :class:`PointCount` so a caller can see it.
We also do not guess whether Z_gamma is meant one- or two-sided: ``gamma`` is passed to
the normal quantile as is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.special import ndtri

from app.domain.errors import InvalidInput
from app.geometry.tolerance import ROUNDOFF_SLACK


class PointCountError(InvalidInput):
    """Inputs outside the formula's domain (K = 1 pole, gamma outside (0, 1), ...)."""


@dataclass(frozen=True)
class PointCount:
    """Result of eq. 1.

    count: ceil(n_exact), at least 2 (a trace needs both ends).
    n_exact: the formula's real value.
    z_gamma: the standard normal gamma-quantile used.
    dn_dk: derivative of n_exact with respect to K at the given K (sign shows the
        direction; positive for 0 < K < 1, contrary to the paper's text).
    """

    count: int
    n_exact: float
    z_gamma: float
    capability_k: float
    confidence: float
    dn_dk: float


def seed_point_count(capability_k: float, confidence: float) -> PointCount:
    """The published eq. 1 as printed: ``N = 0.5 * ((1+K)/(1-K) * Z_gamma)^2``.

    capability_k: K > 0, K != 1 (dimensionless).  confidence: gamma in (0, 1).
    """
    k = float(capability_k)
    g = float(confidence)
    if not math.isfinite(k) or k <= 0:
        raise PointCountError("capability_k must be a positive finite number",
                              field="capability_k", value=capability_k)
    if abs(1.0 - k) < 1e-9:
        raise PointCountError("capability_k = 1 is a pole of eq. 1 (division by 1 - K)",
                              field="capability_k", value=capability_k)
    if not (0.0 < g < 1.0):
        raise PointCountError("confidence must be in (0, 1)", field="confidence",
                              value=confidence)
    z = float(ndtri(g))  # the standard normal's quantile (scipy.stats.norm.ppf's own function)
    factor = (1.0 + k) / (1.0 - k)
    n = 0.5 * (factor * z) ** 2
    dfactor_dk = 2.0 / (1.0 - k) ** 2
    dn_dk = factor * dfactor_dk * z * z
    count = max(2, int(math.ceil(n - ROUNDOFF_SLACK)))
    return PointCount(count=count, n_exact=n, z_gamma=z, capability_k=k, confidence=g,
                      dn_dk=dn_dk)
