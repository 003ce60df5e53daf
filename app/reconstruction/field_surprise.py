"""Which stations the others predict worst: the surprise that places the gap points.

The gap points of a verification (:func:`app.probing.field_verify.gap_points`) go beside the
stations the rest of the touches predict worst: a step, a scratch or an edge the smooth field
cannot represent shows as a station far from what the others say.  A spot touched more than
once (the planner re-touches a trace's end, the outlier screen a suspect touch) is predicted
by its own re-touches when one touch at a time is left out, and reads as unsurprising whatever
the part does there; so each station is predicted here with its whole spot (every touch within
REPEAT_RADIUS_MM of it) left out:

    r_S = (Q_SS)^-1 (Q dz)_S,   cov(r_S) = (Q_SS)^-1,   Q = K^-1

(the leave-one-out residual when the spot is the station alone).

Pure: numpy.  Units: mm.
"""

from __future__ import annotations

import numpy as np

from app.probing.deviation_prior import DeviationPrior, Sites
from app.reconstruction.field_learning import REPEAT_RADIUS_MM, touch_precision


def spot_residuals(prior: DeviationPrior, sites: Sites, dz: np.ndarray,
                   center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(residual (n,) mm, sd (n,) mm): each touch's deviation ``dz`` (n,) less what the
    touches outside its spot predict under ``prior``, and that prediction's sd (field,
    placement terms and noise); ``sites`` (n,), ``center`` (2,) mm the placement terms' centre."""
    dz = np.asarray(dz, dtype=float)
    q = touch_precision(prior, sites, center)
    q_dz = q @ dz
    xy = sites.xy
    near = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1]) <= REPEAT_RADIUS_MM
    residual, sd = np.empty(len(dz)), np.empty(len(dz))
    for i in range(len(dz)):
        spot = np.flatnonzero(near[i])
        cov = np.linalg.inv(q[np.ix_(spot, spot)])
        k = int(np.searchsorted(spot, i))
        residual[i] = cov[k] @ q_dz[spot]
        sd[i] = np.sqrt(cov[k, k])
    return residual, sd


def surprise(prior: DeviationPrior, sites: Sites, dz: np.ndarray, center: np.ndarray, trace: np.ndarray,
             s_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(trace (n,), s_mm (n,), z (n,), residual_mm (n,)) of the touches: the surprise
    :func:`app.probing.field_verify.with_sequential_verification` places its gap points by
    (:func:`spot_residuals`, z = residual / sd)."""
    residual, sd = spot_residuals(prior, sites, dz, center)
    return np.asarray(trace), np.asarray(s_mm), residual / sd, residual
