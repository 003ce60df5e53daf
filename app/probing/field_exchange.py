"""Exchange (local search) refinement of a minimal field design (pure: numpy/scipy).

The field planner's greedy + backward elimination (:mod:`app.probing.field`) ends in a
design from which no single station can be dropped, yet a design with fewer stations often
exists: dropping a small cluster of neighbouring stations and refilling the hole with the
worst-point greedy, then eliminating again, frequently ends with fewer stations than were
removed.  This module runs that move (an iterated local search, ``CLUSTER`` stations at a
time) and keeps every move that does not add stations.

Each move is judged EXACTLY but locally.  The posterior of the whole design is kept over
every candidate in precision form (:class:`DesignPosterior`: P = (K(S, S) + sigma^2 I)^-1,
the kriging weights W = P K(S, U) and the variance; a station added or removed is a rank-one
update).  A move only looks at the candidates within ``TARGET_REACH`` x lambda of the
dropped stations (:class:`_Trial`): there the posterior after the move is the design's
posterior plus one rank-one term per removal / addition, so its cost does not grow with
the board (O(c m) per operation for c stations, m local candidates), and it is conditioned
on every station, far ones included.  (Conditioning on the nearby stations only, the
cheaper "conservative" sub-problem, is useless here: with the jinc kernel's long tails and
a target sd of ~2.5 % of the prior, 2-3 lambda of neighbours leave 1.2-7x the target
variance even for the unchanged design.)  A move that keeps every local target within
target_var and does not add stations is applied to the whole design; if a candidate
elsewhere then exceeds the target, it is taken back.  Trace samples that are not
candidates are not examined: the caller verifies the final design on a fresh posterior
over every trace sample and repairs it with :func:`repair_stations` if needed.

Deterministic: the moves' centres come from a generator with a fixed seed.  Units: mm.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from app.geometry.tolerance import COVARIANCE_JITTER_REL
from app.probing.deviation_prior import DeviationPrior, Sites, jinc_kernel, placement_basis, prior_covariance

CLUSTER = 3                 # stations dropped per move (the centre and its nearest neighbours)
TARGET_REACH = 1.25         # x lambda: local targets around the dropped stations
CANDIDATE_REACH = 0.75      # x lambda: where the refill may put stations
ELIMINATE_REACH = 0.5       # x lambda: old stations the move may drop besides the cluster
TRIALS_PER_STATION = 1      # moves per station of the starting design ...
MIN_TRIALS = 200            # ... and at least this many (small designs are cheap)
EXTRA_ADDS = 2              # a refill may add up to CLUSTER + EXTRA_ADDS stations
SEED = 0
PLATEAU = True              # keep moves that leave the count unchanged (they let the search drift)
# trace samples whose variance under the first design exceeds TIGHT_SAMPLE x target_var join the
# moves' candidates and targets (1: none).  0.5 saves 2-4 more stations on S1's boards and avoids
# the repairs, but costs ~1.5x the exchange's time on the 1000-trace dome (measured; see the report).
TIGHT_SAMPLE = 1.0
PENDING = 32                # rank-one updates of the design's weights kept pending before one GEMM


class DesignPosterior:
    """Posterior of the field at every candidate (N,) given the design's stations, in
    precision form, updated by rank-one adds and removals.

    Stations live in slots (capacity c >= n): precision (c, c) mm^-2 = (K(S, S) +
    sigma^2 I)^-1 on the used slots, zero rows/columns on free ones; var (N,) mm^2 exact;
    the weights W = P K(S, U) (c, N) are ``stale' + x[:, :q] y[:, :q]'`` (stale (N, c): a
    candidate's weights are contiguous; the last q rank-one updates pending, applied PENDING at
    a time by one matrix product); slot_cand (c,) the candidate in each slot (-1 free).
    """

    def __init__(self, prior: DeviationPrior, center: np.ndarray, candidates: Sites, design: np.ndarray) -> None:
        self.prior, self.center, self.candidates = prior, center, candidates
        self.jitter = max(prior.sigma_mm ** 2, COVARIANCE_JITTER_REL * prior.rms_mm ** 2)
        self.rms2 = prior.rms_mm ** 2
        self.basis = placement_basis(candidates, center) * prior.basis_sd          # (N, 6)
        n, size = len(design), len(candidates.xy)
        cap = n + 2 * (CLUSTER + EXTRA_ADDS) + 8
        cov = self.kernel(design, np.arange(size))
        self.precision = np.zeros((cap, cap))
        p = np.linalg.inv(cov[:, design] + self.jitter * np.eye(n))
        self.precision[:n, :n] = (p + p.T) / 2
        weights = self.precision[:n, :n] @ cov
        self.stale = np.zeros((size, cap))
        self.stale[:, :n] = weights.T
        self.var = np.maximum(self.rms2 + np.sum(self.basis ** 2, axis=1) - np.einsum("ij,ij->j", cov, weights), 0.0)
        self.x = np.zeros((cap, PENDING))
        self.y = np.zeros((size, PENDING))
        self.q = 0
        self.slot_cand = np.full(cap, -1, dtype=np.int64)
        self.slot_cand[:n] = design
        self.slot_xy = np.zeros((cap, 2))
        self.slot_xy[:n] = candidates.xy[design]
        self.slot_basis = np.zeros((cap, 6))
        self.slot_basis[:n] = self.basis[design]

    def kernel(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Prior covariance (len a, len b) mm^2 between candidates a and b."""
        xy = self.candidates.xy
        out: np.ndarray = self.rms2 * jinc_kernel(xy[a], xy[b], self.prior.wavelength_mm) + \
            self.basis[a] @ self.basis[b].T
        return out

    @property
    def used(self) -> np.ndarray:
        """(n,) the used slots."""
        out: np.ndarray = np.flatnonzero(self.slot_cand >= 0)
        return out

    def columns(self, idx: np.ndarray) -> np.ndarray:
        """Weights W[:, idx] (c, len idx)."""
        out: np.ndarray = self.stale[idx].T
        if self.q:
            out += np.einsum("ck,mk->cm", self.x[:, :self.q], self.y[idx, :self.q])
        return out

    def _push(self, u: np.ndarray, v: np.ndarray) -> None:
        """W += u v' (u (c,), v (N,)), kept pending."""
        if self.q == PENDING:
            self.stale += self.y @ self.x.T
            self.q = 0
        self.x[:, self.q] = u
        self.y[:, self.q] = v
        self.q += 1

    def remove(self, cand: int) -> None:
        s = int(np.flatnonzero(self.slot_cand == cand)[0])
        d = self.precision[s, s]
        pcol = self.precision[:, s].copy()
        wrow = self.stale[:, s] + self.y[:, :self.q] @ self.x[s, :self.q]
        self.var += wrow * wrow / d
        self._push(-pcol / d, wrow)
        self.precision -= np.outer(pcol, pcol) / d
        self.precision[s, :] = 0.0
        self.precision[:, s] = 0.0
        self.slot_cand[s] = -1

    def add(self, cand: int) -> None:
        free = np.flatnonzero(self.slot_cand < 0)
        if len(free) == 0:
            self._grow()
            free = np.flatnonzero(self.slot_cand < 0)
        f = int(free[0])
        ks = self.rms2 * jinc_kernel(self.candidates.xy[cand:cand + 1], self.slot_xy, self.prior.wavelength_mm)[0] + \
            self.slot_basis @ self.basis[cand]
        k = self.rms2 * jinc_kernel(self.candidates.xy[cand:cand + 1], self.candidates.xy,
                                    self.prior.wavelength_mm)[0] + \
            self.basis @ self.basis[cand]
        cov = k - np.einsum("nc,c->n", self.stale, ks) - \
            self.y[:, :self.q] @ (ks @ self.x[:, :self.q])
        c = max(self.var[cand], 0.0) + self.jitter
        b = self.columns(np.array([cand]))[:, 0]
        self.precision += np.outer(b, b) / c
        self.precision[:, f] = -b / c
        self.precision[f, :] = -b / c
        self.precision[f, f] = 1.0 / c
        u = -b
        u[f] = 1.0
        self._push(u, cov / c)
        self.var = np.maximum(self.var - cov * cov / c, 0.0)
        self.slot_cand[f] = cand
        self.slot_xy[f], self.slot_basis[f] = self.candidates.xy[cand], self.basis[cand]

    def _grow(self) -> None:
        grow = len(self.slot_cand)
        self.precision = np.pad(self.precision, ((0, grow), (0, grow)))
        self.stale = np.concatenate([self.stale, np.zeros((self.stale.shape[0], grow))], axis=1)
        self.x = np.concatenate([self.x, np.zeros((grow, PENDING))])
        self.slot_cand = np.concatenate([self.slot_cand, np.full(grow, -1, dtype=np.int64)])
        self.slot_xy = np.concatenate([self.slot_xy, np.zeros((grow, 2))])
        self.slot_basis = np.concatenate([self.slot_basis, np.zeros((grow, 6))])


class _Trial:
    """One move's posterior over the local candidates U (m,), exact for the whole design:
    the design's posterior covariance there plus the rank-one terms of the move's removals
    (+) and additions (-); the kriging weights (r, m) and precision block (r, r) are kept
    only for the stations the move may remove (r of them, ``cands``)."""

    def __init__(self, design: DesignPosterior, local: np.ndarray, slots: np.ndarray) -> None:
        self.design = design
        self.local = local
        self.wu = design.columns(local)                          # (c, m) the design's weights
        self.var = design.var[local].copy()
        self.xy = np.concatenate([design.candidates.xy[local], design.slot_xy])
        self.basis = np.concatenate([design.basis[local], design.slot_basis])
        self.base: dict[int, np.ndarray] = {}
        self.terms: list[np.ndarray] = []                        # the rank-one vectors a
        self.signs: list[float] = []
        self.cands = [int(design.slot_cand[s]) for s in slots]
        self.w = self.wu[slots]                                  # (r, m)
        self.p = design.precision[np.ix_(slots, slots)]          # (r, r)

    def column(self, u: int) -> np.ndarray:
        """Posterior covariance (m,) mm^2 between local site u and every local site."""
        base = self.base.get(u)
        if base is None:
            d, m = self.design, len(self.local)
            k = d.rms2 * jinc_kernel(self.xy[u:u + 1], self.xy, d.prior.wavelength_mm)[0] + self.basis @ self.basis[u]
            base = self.base[u] = k[:m] - k[m:] @ self.wu
        col = base.copy()
        for sign, a in zip(self.signs, self.terms):
            col += sign * a[u] * a
        return col

    def remove(self, cand: int) -> None:
        i = self.cands.index(cand)
        d = self.p[i, i]
        a = self.w[i] / math.sqrt(d)
        self.var = self.var + a * a
        self.terms.append(a)
        self.signs.append(1.0)
        self.w = self.w - np.outer(self.p[:, i] / d, self.w[i])
        self.p = self.p - np.outer(self.p[:, i], self.p[i]) / d
        keep = np.arange(len(self.cands)) != i
        self.w, self.p = self.w[keep], self.p[keep][:, keep]
        del self.cands[i]

    def add(self, u: int) -> None:
        cov = self.column(u)
        c = max(self.var[u], 0.0) + self.design.jitter
        b = self.w[:, u].copy()
        a = cov / math.sqrt(c)
        self.var = np.maximum(self.var - a * a, 0.0)
        self.terms.append(a)
        self.signs.append(-1.0)
        r = len(self.cands)
        p = np.empty((r + 1, r + 1))
        p[:r, :r] = self.p + np.outer(b, b) / c
        p[:r, r] = p[r, :r] = -b / c
        p[r, r] = 1.0 / c
        self.p = p
        self.w = np.vstack([self.w - np.outer(b, cov / c), cov / c])
        self.cands.append(int(self.local[u]))

    def removal_worst(self, cand: int, targets: np.ndarray) -> float:
        """Largest variance mm^2 over ``targets`` (local indices) without station ``cand``."""
        i = self.cands.index(cand)
        w = self.w[i, targets]
        return float((w * w / self.p[i, i] + self.var[targets]).max())


def _move(design: DesignPosterior, tree: cKDTree, on_trace: np.ndarray, drop: np.ndarray,
          target_var: float) -> list[tuple[str, int]] | None:
    """One exchange move: drop the stations in slots ``drop``, refill with the worst-point
    greedy until the local targets meet target_var, eliminate what became redundant among
    the new and the nearby old stations.  Judged on the candidates near the cluster (exact
    there: conditioned on the whole design).  Returns the operations [("remove" | "add",
    candidate index)] if the move does not add stations, else None."""
    lam = design.prior.wavelength_mm
    dropped_xy = design.slot_xy[drop]
    local = np.unique(np.concatenate([np.asarray(ix, dtype=np.int64) for ix in
                                      tree.query_ball_point(dropped_xy, TARGET_REACH * lam)]))
    dist = np.min(np.linalg.norm(design.candidates.xy[local][:, None, :] - dropped_xy[None], axis=2), axis=1)
    targets = np.flatnonzero(on_trace[local])
    movable = np.flatnonzero(dist <= CANDIDATE_REACH * lam)
    if len(targets) == 0 or len(movable) == 0:
        return None
    used = design.used
    near = np.min(np.linalg.norm(design.slot_xy[used][:, None, :] - dropped_xy[None], axis=2), axis=1)
    slots = np.union1d(used[near <= ELIMINATE_REACH * lam], drop)
    trial = _Trial(design, local, slots)
    dropped = [int(design.slot_cand[s]) for s in drop]
    ops: list[tuple[str, int]] = []
    for cand in dropped:
        trial.remove(cand)
        ops.append(("remove", cand))
    added = 0
    while True:
        t = int(targets[np.argmax(trial.var[targets])])
        if trial.var[t] <= target_var:
            break
        if added == len(drop) + EXTRA_ADDS:
            return None
        cov = trial.column(t)
        gain = cov[movable] ** 2 / (trial.var[movable] + design.jitter)
        u = int(movable[np.argmax(gain)])
        trial.add(u)
        ops.append(("add", int(local[u])))
        added += 1
    removed = 0
    while trial.cands:
        worst = [trial.removal_worst(cand, targets) for cand in trial.cands]
        i = int(np.argmin(worst))
        if worst[i] > target_var:
            break
        ops.append(("remove", trial.cands[i]))
        trial.remove(trial.cands[i])
        removed += 1
    if added - removed > len(drop) - (0 if PLATEAU else 1):
        return None
    return ops


def _net(ops: list[tuple[str, int]]) -> list[tuple[str, int]]:
    """A move's net operations: the posterior depends on the final set of stations only, so a
    station added and removed again (or removed and added again) needs no update."""
    count: dict[int, int] = {}
    for op, cand in ops:
        count[cand] = count.get(cand, 0) + (1 if op == "add" else -1)
    return [("remove", c) for c, k in count.items() if k < 0] + [("add", c) for c, k in count.items() if k > 0]


def _apply(design: DesignPosterior, ops: list[tuple[str, int]], undo: bool = False) -> None:
    """Apply a move's net operations to the design's posterior (or take them back)."""
    for op, cand in (reversed(ops) if undo else ops):
        if (op == "remove") != undo:
            design.remove(cand)
        else:
            design.add(cand)


def exchange_stations(prior: DeviationPrior, center: np.ndarray, candidates: Sites, on_trace: np.ndarray,
                      design: np.ndarray, target_var: float, keep_at_least: int,
                      trials: int | None = None, seed: int = SEED) -> np.ndarray:
    """Exchange refinement of ``design`` (n,) indices into ``candidates`` (N,) (Sites; on_trace
    (N,) bool marks the ones on traces, the targets).  Runs ``trials`` moves (default
    max(MIN_TRIALS, TRIALS_PER_STATION x n); none if TRIALS_PER_STATION is 0), each centred
    on a station drawn with a fixed seed, and keeps every move that does not add stations and keeps every on-trace
    candidate within target_var.  Returns the new design's candidate indices (no more than n; the caller
    verifies it on every trace sample)."""
    design = np.asarray(design, dtype=np.int64)
    total = int(max(MIN_TRIALS * (TRIALS_PER_STATION > 0), TRIALS_PER_STATION * len(design))) if trials is None \
        else int(trials)
    if len(design) <= max(keep_at_least, CLUSTER) or total <= 0:
        return design
    tree = cKDTree(candidates.xy)
    post = DesignPosterior(prior, center, candidates, design)
    on = np.flatnonzero(on_trace)
    rng = np.random.default_rng(seed)
    for _ in range(total):
        used = post.used
        if len(used) <= max(keep_at_least, CLUSTER):
            break
        c0 = post.slot_xy[used[rng.integers(len(used))]]
        d = np.linalg.norm(post.slot_xy[used] - c0, axis=1)
        drop = used[np.argsort(d, kind="stable")[:CLUSTER]]
        ops = _move(post, tree, on_trace, drop, target_var)
        if ops is None:
            continue
        ops = _net(ops)
        _apply(post, ops)
        if post.var[on].max() > target_var or len(post.used) < keep_at_least:
            _apply(post, ops, undo=True)
    return np.sort(post.slot_cand[post.used])


def repair_stations(prior: DeviationPrior, center: np.ndarray, stations: Sites, where: Sites,
                    precision: np.ndarray, weights: np.ndarray, var: np.ndarray, target_var: float
                    ) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray]:
    """Worst-point greedy over the points ``where`` (N,) until every one has variance <=
    target_var: each step adds, as a station, the point that lowers the worst point's
    variance most.  precision (n, n), weights (n, N), var (N,) describe the posterior given
    ``stations`` (n,) (as :func:`app.probing.field_posterior.posterior_parts` makes them).  Returns the
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
