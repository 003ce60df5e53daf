"""Exchange (local search) refinement of a minimal field design (pure: numpy/scipy).

The field planner's greedy + backward elimination (:mod:`app.probing.field`) ends in a
design from which no single station can be dropped, yet a design with fewer stations often
exists: dropping a small cluster of neighbouring stations and refilling the hole with the
worst-point greedy, then eliminating again, frequently ends with fewer stations than were
removed.  This module runs that move (an iterated local search, ``CLUSTER`` stations at a
time) and keeps every move that does not add stations.

A move is judged on a LOCAL sub-problem, so its cost does not grow with the board: the
targets are the on-trace candidates within ``TARGET_REACH`` x lambda of the dropped
stations, the stations the posterior is conditioned on are the design's stations within
``STATION_REACH`` x lambda of them.  A posterior from a subset of the stations has at least
the variance of the posterior from all of them, so a move that meets the target locally
meets it at those targets globally; points farther away are not examined (the variance a
dropped station leaves behind decays over ~0.6 lambda, the jinc kernel's first zero), so
the caller verifies the final design on a fresh posterior over every trace sample and
repairs it with :func:`repair_stations` if needed.

The local posterior is kept in precision form: P = (K(S, S) + sigma^2 I)^-1 (n, n), the
kriging weights W = P K(S, U) (n, m) over the local sites U and their variance var (m,);
adding or removing a station is a rank-one update of all three (O(n m)).

Deterministic: the moves' centres come from a generator with a fixed seed.  Units: mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from app.geometry.tolerance import COVARIANCE_JITTER_REL
from app.probing.deviation_prior import DeviationPrior, Sites, prior_covariance, prior_variance

CLUSTER = 3                 # stations dropped per move (the centre and its nearest neighbours)
TARGET_REACH = 1.25         # x lambda: local targets around the dropped stations
STATION_REACH = 2.0         # x lambda: stations the local posterior is conditioned on
CANDIDATE_REACH = 0.75      # x lambda: where the refill may put stations
ELIMINATE_REACH = 0.5       # x lambda: old stations the move may drop besides the cluster
TRIALS_PER_STATION = 2      # moves per station of the starting design
EXTRA_ADDS = 2              # a refill may add up to CLUSTER + EXTRA_ADDS stations
SEED = 0
PLATEAU = True             # keep moves that leave the count unchanged (they let the search drift)


@dataclass
class LocalPosterior:
    """Posterior over local sites U (m,) given stations (n,), in precision form.

    stations: list of candidate indices; precision (n, n) mm^-2; weights (n, m) = P K(S, U);
    var (m,) mm^2.  ``sites`` are the sites of U, ``cand`` (m,) their candidate indices."""

    prior: DeviationPrior
    center: np.ndarray
    jitter: float
    sites: Sites
    cand: np.ndarray
    stations: list[int]
    station_sites: Sites
    precision: np.ndarray
    weights: np.ndarray
    var: np.ndarray

    @classmethod
    def build(cls, prior: DeviationPrior, center: np.ndarray, candidates: Sites, local: np.ndarray,
              stations: np.ndarray) -> "LocalPosterior":
        """From one factorisation: local sites = candidates[local], stations = candidates[stations]."""
        jitter = max(prior.sigma_mm ** 2, COVARIANCE_JITTER_REL * prior.rms_mm ** 2)
        sites = candidates.take(local)
        st = candidates.take(stations)
        var = prior_variance(prior, sites, center)
        n = len(stations)
        if n:
            precision = np.linalg.inv(prior_covariance(prior, st, st, center) + jitter * np.eye(n))
            precision = (precision + precision.T) / 2
            cov = prior_covariance(prior, st, sites, center)
            weights = precision @ cov
            var = np.maximum(var - np.einsum("ij,ij->j", cov, weights), 0.0)
        else:
            precision, weights = np.zeros((0, 0)), np.zeros((0, len(local)))
        return cls(prior, center, jitter, sites, local, [int(s) for s in stations], st, precision, weights, var)

    def cov_with(self, site: Sites) -> np.ndarray:
        """Posterior covariance (m,) mm^2 between one site and every local site."""
        k = prior_covariance(self.prior, site, self.sites, self.center)[0]
        if len(self.stations):
            k -= prior_covariance(self.prior, site, self.station_sites, self.center)[0] @ self.weights
        out: np.ndarray = k
        return out

    def add(self, u: int) -> None:
        """Add a station at local site u (rank-one update of P, W, var)."""
        cov = self.cov_with(self.sites.take(np.array([u])))
        c = max(self.var[u], 0.0) + self.jitter
        b = self.weights[:, u].copy()
        n = len(self.stations)
        precision = np.empty((n + 1, n + 1))
        precision[:n, :n] = self.precision + np.outer(b, b) / c
        precision[:n, n] = precision[n, :n] = -b / c
        precision[n, n] = 1.0 / c
        self.precision = precision
        self.weights = np.vstack([self.weights - np.outer(b, cov / c), cov / c])
        self.var = np.maximum(self.var - cov * cov / c, 0.0)
        self.stations.append(int(self.cand[u]))
        self.station_sites = Sites(np.vstack([self.station_sites.xy, self.sites.xy[u]]),
                                   np.vstack([self.station_sites.grad, self.sites.grad[u]]))

    def remove(self, i: int) -> None:
        """Remove the i-th station (rank-one downdate of P, W, var)."""
        d = self.precision[i, i]
        self.var = self.var + self.weights[i] ** 2 / d
        self.weights = self.weights - np.outer(self.precision[:, i] / d, self.weights[i])
        self.precision = self.precision - np.outer(self.precision[:, i] / d, self.precision[i])
        mask = np.ones(len(self.stations), dtype=bool)
        mask[i] = False
        self.weights, self.precision = self.weights[mask], self.precision[mask][:, mask]
        del self.stations[i]
        self.station_sites = self.station_sites.take(np.flatnonzero(mask))

    def removal_worst(self, i: int, targets: np.ndarray) -> float:
        """Largest variance mm^2 over ``targets`` (local indices) if station i were removed."""
        w = self.weights[i, targets]
        return float((w * w / self.precision[i, i] + self.var[targets]).max())


def _local(post: LocalPosterior, local: np.ndarray) -> LocalPosterior:
    """The posterior ``post`` (over every candidate, given every station) restricted to the
    candidates ``local``: the same stations and precision, the weights' columns of ``local``."""
    return LocalPosterior(post.prior, post.center, post.jitter, post.sites.take(local), post.cand[local],
                          list(post.stations), post.station_sites, post.precision.copy(),
                          post.weights[:, local].copy(), post.var[local].copy())


def _move(post: LocalPosterior, tree: cKDTree, on_trace: np.ndarray, drop: np.ndarray,
          target_var: float) -> list[tuple[str, int]] | None:
    """One exchange move on the posterior ``post`` (every candidate, every station): drop the
    stations ``drop`` (positions in post.stations), refill with the worst-point greedy until
    the local targets meet target_var, eliminate what became redundant.  Judged on the
    candidates near the cluster only (exact there: the precision is the whole design's).
    Returns the operations [("remove" | "add", candidate index)] if the move does not add
    stations, else None."""
    lam = post.prior.wavelength_mm
    dropped_xy = post.station_sites.xy[drop]
    local = np.unique(np.concatenate([np.asarray(ix, dtype=np.int64) for ix in
                                      tree.query_ball_point(dropped_xy, TARGET_REACH * lam)]))
    dist = np.min(np.linalg.norm(post.sites.xy[local][:, None, :] - dropped_xy[None], axis=2), axis=1)
    targets = np.flatnonzero(on_trace[local])
    movable = np.flatnonzero(dist <= CANDIDATE_REACH * lam)
    if len(targets) == 0 or len(movable) == 0:
        return None
    sub = _local(post, local)
    near = np.min(np.linalg.norm(post.station_sites.xy[:, None, :] - dropped_xy[None], axis=2), axis=1)
    removable = {post.stations[i] for i in np.flatnonzero(near <= ELIMINATE_REACH * lam)}
    ops: list[tuple[str, int]] = []
    for s in [post.stations[i] for i in drop]:
        sub.remove(sub.stations.index(s))
        removable.discard(s)
        ops.append(("remove", s))
    added = 0
    while True:
        t = int(targets[np.argmax(sub.var[targets])])
        if sub.var[t] <= target_var:
            break
        if added == len(drop) + EXTRA_ADDS:
            return None
        cov = sub.cov_with(sub.sites.take(np.array([t])))
        gain = cov[movable] ** 2 / (sub.var[movable] + sub.jitter)
        u = int(movable[np.argmax(gain)])
        sub.add(u)
        removable.add(int(sub.cand[u]))
        ops.append(("add", int(sub.cand[u])))
        added += 1
    removed = 0
    while removable:
        best, best_s = math.inf, -1
        for s in removable:
            w = sub.removal_worst(sub.stations.index(s), targets)
            if w < best:
                best, best_s = w, s
        if best > target_var:
            break
        removable.discard(best_s)
        sub.remove(sub.stations.index(best_s))
        ops.append(("remove", best_s))
        removed += 1
    if added - removed > len(drop) - (0 if PLATEAU else 1):
        return None
    return ops


def _apply(post: LocalPosterior, ops: list[tuple[str, int]]) -> None:
    """Replay a move's operations on the whole posterior (candidate index = site index)."""
    for op, s in ops:
        if op == "remove":
            post.remove(post.stations.index(s))
        else:
            post.add(s)


def exchange_stations(prior: DeviationPrior, center: np.ndarray, candidates: Sites, on_trace: np.ndarray,
                      design: np.ndarray, target_var: float, keep_at_least: int,
                      trials: int | None = None, seed: int = SEED) -> np.ndarray:
    """Exchange refinement of ``design`` (n,) indices into ``candidates`` (N,) (Sites; on_trace
    (N,) bool marks the ones on traces, the targets).  Runs ``trials`` moves (default
    TRIALS_PER_STATION x n), each centred on a station drawn with a fixed seed, and keeps
    every move that does not add stations and keeps every on-trace candidate within
    target_var.  Returns the new design's candidate indices (no more than n; the caller
    verifies it on every trace sample)."""
    design = np.asarray(design, dtype=np.int64)
    total = int(TRIALS_PER_STATION * len(design)) if trials is None else int(trials)
    if len(design) <= max(keep_at_least, CLUSTER) or total <= 0:
        return design
    tree = cKDTree(candidates.xy)
    post = LocalPosterior.build(prior, center, candidates, np.arange(len(candidates.xy)), design)
    on = np.flatnonzero(on_trace)
    rng = np.random.default_rng(seed)
    for _ in range(total):
        if len(post.stations) <= max(keep_at_least, CLUSTER):
            break
        c0 = post.station_sites.xy[rng.integers(len(post.stations))]
        d = np.linalg.norm(post.station_sites.xy - c0, axis=1)
        drop = np.argsort(d, kind="stable")[:CLUSTER]
        ops = _move(post, tree, on_trace, drop, target_var)
        if ops is None:
            continue
        saved = (list(post.stations), post.station_sites, post.precision, post.weights, post.var)
        _apply(post, ops)
        if post.var[on].max() > target_var or len(post.stations) < keep_at_least:
            post.stations, post.station_sites, post.precision, post.weights, post.var = saved
    return np.array(post.stations, dtype=np.int64)


def repair_stations(prior: DeviationPrior, center: np.ndarray, stations: Sites, where: Sites,
                    precision: np.ndarray, weights: np.ndarray, var: np.ndarray, target_var: float
                    ) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray]:
    """Worst-point greedy over the points ``where`` (N,) until every one has variance <=
    target_var: each step adds, as a station, the point that lowers the worst point's
    variance most.  precision (n, n), weights (n, N), var (N,) describe the posterior given
    ``stations`` (n,) (as :func:`app.probing.field.posterior_parts` makes them).  Returns the
    added points' indices into ``where`` and the updated precision, weights, var."""
    jitter = max(prior.sigma_mm ** 2, COVARIANCE_JITTER_REL * prior.rms_mm ** 2)
    added: list[int] = []
    xy, grad = stations.xy, stations.grad
    while var.max() > target_var and len(added) < len(var):
        t = int(np.argmax(var))
        site = where.take(np.array([t]))
        cov_t = prior_covariance(prior, site, where, center)[0] - \
            prior_covariance(prior, site, Sites(xy, grad), center)[0] @ weights
        j = int(np.argmax(cov_t * cov_t / (var + jitter)))
        sj = where.take(np.array([j]))
        cov = prior_covariance(prior, sj, where, center)[0] - \
            prior_covariance(prior, sj, Sites(xy, grad), center)[0] @ weights
        c = max(var[j], 0.0) + jitter
        b = weights[:, j].copy()
        n = len(precision)
        grown = np.empty((n + 1, n + 1))
        grown[:n, :n] = precision + np.outer(b, b) / c
        grown[:n, n] = grown[n, :n] = -b / c
        grown[n, n] = 1.0 / c
        precision = grown
        weights = np.vstack([weights - np.outer(b, cov / c), cov / c])
        var = np.maximum(var - cov * cov / c, 0.0)
        xy, grad = np.vstack([xy, sj.xy]), np.vstack([grad, sj.grad])
        added.append(j)
    return added, precision, weights, var
