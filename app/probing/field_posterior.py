"""The field planner's fresh posterior over a board's trace samples, in column blocks.

A design's stations S (n,) and the trace samples ``where`` (N,: thousands on a board) give
the posterior variance at every sample from one factorisation; the kriging weights (n, N)
are kept only when backward elimination (:func:`eliminate_redundant`) will downdate them.
The prior covariance K(S, where) is built and used :data:`SD_CHUNK` columns at a time, so
without the weights a fresh posterior holds one block of K(S, where) and its kernel's
temporaries, never an (n, N) array (on the 1000-trace dome's sequential rounds: ~600
stations x ~8000 samples, 38 MB of float64 for the weights alone).

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from app.geometry.tolerance import COVARIANCE_JITTER_REL
from app.probing.deviation_prior import DeviationPrior, Sites, prior_covariance, prior_variance

SD_CHUNK = 4096  # columns of K(S, where) (and of the kriging weights) handled at once


class KernelRows:
    """The unit kernel (n, N) of n stations and N sites held as its rows (n arrays (N,),
    e.g. views into the blocks they were computed in, kept across plans): a block of columns
    is copied out when it is used (:meth:`block`), so the (n, N) matrix itself is never
    assembled (38 MB at ~600 stations x ~8000 samples)."""

    def __init__(self, rows: list[np.ndarray], columns: int) -> None:
        self.rows = rows
        self.shape = (len(rows), columns)

    def block(self, lo: int, hi: int) -> np.ndarray:
        """Columns ``lo:hi`` (n, hi - lo), C-contiguous: the same numbers as the rows'."""
        if not self.rows:
            return np.zeros((0, hi - lo))
        return np.stack([row[lo:hi] for row in self.rows])


@dataclass
class PosteriorParts:
    """The posterior of the field at points ``where`` (N,) given stations S (n,):
    precision (n, n) = (K(S, S) + sigma^2 I)^-1, weights (n, N) = precision K(S, where)
    (the kriging weights; None when not kept), var (N,) mm^2 posterior variance, keep (n,)
    station indices."""

    precision: np.ndarray
    weights: np.ndarray | None
    var: np.ndarray
    keep: np.ndarray


def posterior_parts(prior: DeviationPrior, stations: Sites, where: Sites, center: np.ndarray, *,
                    weights: bool = True, block: int = SD_CHUNK,
                    jinc: np.ndarray | KernelRows | None = None) -> PosteriorParts:
    """:class:`PosteriorParts` from one factorisation (cost O(n^2 N)), K(S, where) in blocks
    of ``block`` columns; with ``weights`` False the (n, N) kriging weights are not kept
    (``weights`` None: only what the variance needs, one block at a time); ``jinc``: the unit
    kernel (n, N) of the stations and ``where`` (or its rows) when the caller has it."""
    n = len(stations.xy)
    jitter = max(prior.sigma_mm ** 2, COVARIANCE_JITTER_REL * prior.rms_mm ** 2)
    precision = np.linalg.inv(prior_covariance(prior, stations, stations, center) + jitter * np.eye(n))
    precision = (precision + precision.T) / 2
    var = prior_variance(prior, where, center)
    kept = np.empty((n, len(var))) if weights else None
    for lo in range(0, len(var), block):
        hi = min(lo + block, len(var))
        block_of = where.take(np.arange(lo, hi))
        if isinstance(jinc, KernelRows):  # a copy of the kept rows' columns: spent on the covariance
            cov = prior_covariance(prior, stations, block_of, center, jinc.block(lo, hi), spend_jinc=True)
        else:
            cov = prior_covariance(prior, stations, block_of, center,
                                   None if jinc is None else np.ascontiguousarray(jinc[:, lo:hi]))
        solved = precision @ cov
        var[lo:hi] -= np.einsum("ij,ij->j", cov, solved)
        if kept is not None:
            kept[:, lo:hi] = solved
        del cov, solved
    return PosteriorParts(precision, kept, np.maximum(var, 0.0), np.arange(n))


def eliminate_redundant(parts: PosteriorParts, target_var: float, keep_at_least: int) -> PosteriorParts:
    """Backward elimination: drop stations while the largest posterior variance over the
    points stays <= target_var.  Returns the parts of the kept stations (``keep``: their
    indices, ascending, into the stations ``parts`` was made from).  ``parts`` must hold
    the kriging weights.

    A greedy design adds each station for the worst point of its moment; later stations
    often make an early one redundant.  With P = (K(S, S) + sigma^2 I)^-1 and the kriging
    weights W = P K(S, where), removing station j raises the variance at every point u by
    exactly ``W[j, u]^2 / P[j, j]``.  Each step removes the station whose removal leaves the
    smallest largest variance (if that meets the target) and downdates P and W by rank one
    (``P -= P[:, j] P[j, :] / P[j, j]``, the same for W): a step costs O(n N).
    """
    precision, weights, var, keep = parts.precision, parts.weights, parts.var, parts.keep
    if weights is None:
        raise ValueError("backward elimination needs the kriging weights (posterior_parts(weights=True))")
    while len(keep) > keep_at_least:
        d = np.diag(precision).copy()
        worst = np.empty(len(keep))
        for lo in range(0, len(var), SD_CHUNK):
            w = weights[:, lo:lo + SD_CHUNK]
            worst_part = (w * w / d[:, None] + var[None, lo:lo + SD_CHUNK]).max(axis=1)
            worst = worst_part if lo == 0 else np.maximum(worst, worst_part)
        j = int(np.argmin(worst))
        if worst[j] > target_var:
            break
        var = var + weights[j] ** 2 / d[j]
        weights = weights - np.outer(precision[:, j] / d[j], weights[j])
        precision = precision - np.outer(precision[:, j] / d[j], precision[j])
        mask = np.ones(len(keep), dtype=bool)
        mask[j] = False
        weights, precision, keep = weights[mask], precision[mask][:, mask], keep[mask]
    return PosteriorParts(precision, weights, var, keep)


def posterior_sd(prior: DeviationPrior, stations: Sites, where: Sites, center: np.ndarray) -> np.ndarray:
    """Posterior sd (m,) mm of the field at ``where`` given stations (fresh factorisation)."""
    jitter = max(prior.sigma_mm ** 2, COVARIANCE_JITTER_REL * prior.rms_mm ** 2)
    k = prior_covariance(prior, stations, stations, center)
    low = np.linalg.cholesky(k + jitter * np.eye(len(k)))
    out = np.empty(len(where.xy))
    for lo in range(0, len(out), SD_CHUNK):
        part = where.take(np.arange(lo, min(lo + SD_CHUNK, len(out))))
        a = solve_triangular(low, prior_covariance(prior, stations, part, center), lower=True)
        out[lo:lo + len(part.xy)] = prior_variance(prior, part, center) - np.sum(a * a, axis=0)
    return np.sqrt(np.maximum(out, 0.0))
