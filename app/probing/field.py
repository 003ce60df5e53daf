"""The field probe planner (``probe_plan`` method ``"field"``): stations for a whole board.

The real part's deviation from CAD is ONE field over the part — a band-limited machining
error plus one rigid placement (:mod:`app.probing.deviation_prior`) — however many traces
lie on it.  This planner chooses stations over the region the traces cover
(:mod:`app.probing.field_region`) so that the largest posterior sd of the field over every
point of every trace meets the target (``coverage`` x sd <= ``target_error_mm``), with the
fewest stations the design rule finds (or a given count).  Stations lie on the traces
(``stations="on_traces"``) or anywhere on the part's top the probe reaches
(``"anywhere_on_top"``).

Algorithm (cost set by the covered area and lambda, not by the number of traces): greedy
sequential design over a bounded set U of candidate/target points (one per lambda / 8
cell).  Each step adds the candidate with the largest posterior variance; the posterior is
kept as the rows ``R = L^-1 K(S, U)`` of the stations' Cholesky factor L (K(S, S) + noise =
L L'), extended by ONE row per added station (a rank-one update: ``r = (K(j, U) - R[:, j]' R)
/ sqrt(var_j + sigma^2)``, ``var -= r^2``), so n stations cost O(n^2 |U|) in all instead of a
factorisation per step.  The automatic count first takes the first prefix of the greedy
sequence that meets the target on every trace sample (spacing lambda / 16, from a fresh
factorisation); then backward elimination (:func:`eliminate_redundant`, rank-one downdates
of the precision and the kriging weights) drops, one at a time, the stations whose removal
keeps every sample within the target (5-7 % of a greedy design), so no single station of
the final design can be left out.  The largest sd is reported overall and per trace.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import partial
from typing import Literal

import numpy as np
from scipy.linalg import solve_triangular

from app.geometry.tolerance import COVARIANCE_JITTER_REL
from app.geometry.traces import as_trace_polyline
from app.probing.deviation_prior import (
    DeviationPrior,
    Sites,
    jinc_kernel,
    placement_basis,
    prior_covariance,
)
from app.probing.field_dof import Deferred, region_dof
from app.probing.field_exchange import TIGHT_SAMPLE, exchange_stations, repair_stations
from app.probing.field_posterior import SD_CHUNK as SD_CHUNK  # re-exported: the planner's names stay importable here
from app.probing.field_posterior import PosteriorParts, eliminate_redundant, posterior_parts
from app.probing.field_posterior import posterior_sd as posterior_sd
from app.probing.field_region import FieldRegion, TopSampler, TracePoints, field_region
from app.probing.field_reuse import PlanReuse
from app.probing.selection import PlanError, PlanParams, ProbePlan

StationMode = Literal["on_traces", "anywhere_on_top"]
STATION_MODES: tuple[str, ...] = ("on_traces", "anywhere_on_top")
MAX_FIELD_PROBES = 4000


class GreedyField:
    """Posterior of the field over sites U (N,) as stations are added one at a time.

    rows: (n, N) = L^-1 K(S, U) for the n stations S so far, with L (n, n) the lower
    Cholesky factor of K(S, S) + jitter I; var: (N,) posterior variance mm^2 (noise-free
    field); chosen: (n,) indices into U in the order added.  :meth:`extend` appends sites
    to U without refactorising (one triangular solve for the new columns).
    """

    def __init__(self, prior: DeviationPrior, sites: Sites, center: np.ndarray) -> None:
        self.prior = prior
        self.center = center
        self.jitter = max(prior.sigma_mm ** 2, COVARIANCE_JITTER_REL * prior.rms_mm ** 2)
        self.sites = Sites(np.zeros((0, 2)), np.zeros((0, 2)))
        self.basis = np.zeros((0, 6))
        self.prior_var = np.zeros(0)
        self.var = np.zeros(0)
        self.rows = np.empty((16, 0))
        self.low = np.zeros((16, 16))
        self.chosen: list[int] = []
        self._column: tuple[int, int, np.ndarray] | None = None   # (t, n, posterior cov of t)
        self.extend(sites)

    def extend(self, sites: Sites) -> None:
        """Append sites (m,) to U: their rows L^-1 K(S, new) and posterior variance."""
        n = len(self.chosen)
        basis = placement_basis(sites, self.center) * self.prior.basis_sd         # (m, 6)
        prior_var = self.prior.rms_mm ** 2 + np.sum(basis ** 2, axis=1)
        if n:  # the rows in use only: the new R is made without the room for more stations
            self.rows = self.rows[:n]
        rows = np.empty((len(self.rows), len(prior_var)))
        var = prior_var.copy()
        if n:
            stations = self.sites.take(np.array(self.chosen))
            rows[:n] = solve_triangular(self.low[:n, :n],
                                        prior_covariance(self.prior, stations, sites, self.center), lower=True)
            var = np.maximum(var - np.sum(rows[:n] ** 2, axis=0), 0.0)
        self.sites = Sites(np.concatenate([self.sites.xy, sites.xy]), np.concatenate([self.sites.grad, sites.grad]))
        self.basis = np.concatenate([self.basis, basis])
        self.prior_var = np.concatenate([self.prior_var, prior_var])
        self.var = np.concatenate([self.var, var])
        self.rows = np.concatenate([self.rows, rows], axis=1)

    def kernel_row(self, j: int) -> np.ndarray:
        """Prior covariance (N,) mm^2 between site j and every site."""
        jinc = jinc_kernel(self.sites.xy[j:j + 1], self.sites.xy, self.prior.wavelength_mm)[0]
        out: np.ndarray = self.prior.rms_mm ** 2 * jinc + self.basis @ self.basis[j]
        return out

    def posterior_cov(self, t: int) -> np.ndarray:
        """Posterior covariance (N,) mm^2 between site t and every site: K(t, U) - R[:, t]' R.
        The last one is kept: the greedy usually adds the very site it just scored for."""
        n = len(self.chosen)
        if self._column is not None and self._column[:2] == (t, n):
            return self._column[2]
        cov = self.kernel_row(t)
        if n:
            cov -= self.rows[:n, t] @ self.rows[:n]
        self._column = (t, n, cov)
        return cov

    def gain_for(self, t: int) -> np.ndarray:
        """Variance drop (N,) mm^2 at site t if a station were added at each site."""
        cov = self.posterior_cov(t)
        out: np.ndarray = cov * cov / (self.var + self.jitter)
        return out

    def add_many(self, sites: np.ndarray) -> None:
        """Add stations at the sites ``sites`` (m,) in that order, at once: the factor m
        :meth:`add` calls make, by blocks (the posterior covariance C (m, N) of the new sites
        given the stations so far, C's own (m, m) block + jitter I = L2 L2', the new rows
        L2^-1 C): level-3 BLAS instead of m matrix-vector products over R, the same numbers
        to rounding.  The room is exactly the stations (as after :meth:`extend`)."""
        js = np.asarray(sites, dtype=int)
        n, m = len(self.chosen), len(js)
        if m == 0:
            return
        rows = np.empty((n + m, len(self.var)))
        rows[:n] = self.rows[:n]
        low = np.zeros((n + m, n + m))
        low[:n, :n] = self.low[:n, :n]
        cov = prior_covariance(self.prior, self.sites.take(js), self.sites, self.center)   # (m, N)
        if n:
            low[n:, :n] = self.rows[:n, js].T
            cov -= low[n:, :n] @ self.rows[:n]
        low[n:, n:] = np.linalg.cholesky(cov[:, js] + self.jitter * np.eye(m))
        rows[n:] = solve_triangular(low[n:, n:], cov, lower=True, check_finite=False)
        self.rows, self.low, self._column = rows, low, None
        self.var = np.maximum(self.var - np.einsum("ij,ij->j", rows[n:], rows[n:]), 0.0)
        self.chosen.extend(int(j) for j in js)

    def add(self, j: int) -> None:
        """Add a station at site j: one new row of R and of L, variance downdated."""
        n = len(self.chosen)
        if n == len(self.rows):  # room for half as many stations again
            self.rows = np.concatenate([self.rows, np.empty((max(n // 2, 1), self.rows.shape[1]))])
            low = np.zeros((len(self.rows), len(self.rows)))
            low[:n, :n] = self.low[:n, :n]
            self.low = low
        row = self.posterior_cov(j) / 1.0   # a copy: the kept column stays as it was
        pivot = math.sqrt(max(self.var[j], 0.0) + self.jitter)
        self.low[n, :n] = self.rows[:n, j]
        self.low[n, n] = pivot
        row /= pivot
        self.rows[n] = row
        self._column = None
        self.var = np.maximum(self.var - row * row, 0.0)
        self.chosen.append(int(j))


def greedy_sequence(greedy: GreedyField, targets: np.ndarray, count: int | None, target_var: float,
                    min_count: int, first_candidate: int = 0) -> int:
    """Run the greedy design: ``count`` stations in all, or (count None) until the largest
    variance over ``targets`` (indices into U) is <= target_var with >= min_count stations.
    Every site of U is a candidate.

    Each step finds the worst target t and adds the candidate j that lowers its variance
    most, ``cov(j, t)^2 / (var_j + sigma^2)`` (the posterior covariance column of t costs
    O(n N)).  On traces this picks the worst point itself or a neighbour; with free
    candidates it avoids points off the traces whose own variance is large but irrelevant.
    Sites before ``first_candidate`` (stations already touched) are not candidates: a second
    touch there is a site of U at the same point.  Returns the number of stations chosen."""
    most = min(MAX_FIELD_PROBES, len(greedy.var)) if count is None else int(count)
    while len(greedy.chosen) < most:
        worst = int(targets[np.argmax(greedy.var[targets])])
        if count is None and len(greedy.chosen) >= min_count and greedy.var[worst] <= target_var:
            break
        gain = greedy.gain_for(worst)
        gain[:first_candidate] = -np.inf
        greedy.add(int(np.argmax(gain)))
    return len(greedy.chosen)


@dataclass(frozen=True, eq=False)
class FieldPlan:
    """Stations of a board in probing order.

    xy (n, 2), z (n,) nominal top, grad (n, 2) nominal slope, normals (n, 3);
    trace (n,) index of the trace a station lies on (-1: off the traces), s_mm (n,) its
    arc length there (NaN off the traces).  center (2,) mm: the placement terms' centre.
    max_sd_mm: largest posterior sd over every trace sample; trace_sd_mm (T,) per trace.
    dof: the field's degrees of freedom at the target (the truncation dimension,
    :mod:`app.probing.field_dof`; counted when first read); nyquist_dof: the rule-of-thumb ``A / (lambda/2)^2 + 6``;
    area_mm2: the covered area.  order: (n,) the
    order in which the greedy added them (index into the stations; with the automatic count
    the stations elimination dropped are not in it).  verify (n,) bool or None: the last
    ``k`` points are verification points (:func:`app.probing.field_verify.with_verification`),
    not stations.
    """

    xy: np.ndarray
    z: np.ndarray
    grad: np.ndarray
    trace: np.ndarray
    s_mm: np.ndarray
    center: np.ndarray
    max_sd_mm: float
    trace_sd_mm: np.ndarray
    area_mm2: float
    stations_mode: str
    order: np.ndarray
    nyquist_dof: float = math.nan
    verify: np.ndarray | None = None
    dof: Deferred = Deferred()

    @property
    def verify_mask(self) -> np.ndarray:
        """(n,) bool: the verification points (touched last, never used in the fit)."""
        return np.zeros(len(self.xy), dtype=bool) if self.verify is None else self.verify

    @property
    def count(self) -> int:
        return int(len(self.xy))

    @property
    def normals(self) -> np.ndarray:
        n = np.column_stack([-self.grad, np.ones(len(self.grad))])
        out: np.ndarray = n / np.linalg.norm(n, axis=1, keepdims=True)
        return out

    @property
    def points(self) -> np.ndarray:
        return np.column_stack([self.xy, self.z])

    @property
    def sites(self) -> Sites:
        return Sites(self.xy, self.grad)

    @property
    def stations_per_trace(self) -> np.ndarray:
        """(T,) int: how many stations lie on each trace (off-trace stations count for none)."""
        on = (self.trace >= 0) & ~self.verify_mask
        counts: np.ndarray = np.bincount(self.trace[on], minlength=len(self.trace_sd_mm))
        return counts

    def probe_plan(self) -> ProbePlan:
        """The stations as a ProbePlan "field" for the probe program, in probing order; an
        off-trace station's arc length (NaN here) is -1 there."""
        return ProbePlan("field", np.where(np.isnan(self.s_mm), -1.0, self.s_mm), self.points, self.normals)


def travel_order(xy: np.ndarray, band_mm: float) -> np.ndarray:
    """Serpentine visiting order (n,) of points (n, 2): bands of ``band_mm`` in y, x up then down."""
    if len(xy) == 0:
        return np.zeros(0, dtype=int)
    band = np.floor((xy[:, 1] - xy[:, 1].min()) / band_mm).astype(int)
    key_x = np.where(band % 2 == 0, xy[:, 0], -xy[:, 0])
    return np.lexsort((key_x, band))


def plan_field(nominals: Sequence[object], params: PlanParams | None = None,
               stations: str = "on_traces", top: TopSampler | None = None,
               fixed: Sites | None = None, reuse: PlanReuse | None = None) -> FieldPlan:
    """Field stations for every trace in ``nominals`` (TracePolyline-like, one frame).

    params: the deviation prior, ``target_error_mm``, ``coverage``, ``min_count`` and an
    optional total ``count``.  stations: "on_traces" or "anywhere_on_top" (needs ``top``,
    the part's nominal top).  fixed: stations already touched (a sequential plan's
    earlier rounds): the design starts from them and returns only the stations it adds
    (none when they already meet the target; its sd figures count them).  reuse: what the
    plans of one round share (:class:`app.probing.field_reuse.PlanReuse`).  Raises PlanError
    for bad input.
    """
    params = params or PlanParams()
    if stations not in STATION_MODES:
        raise PlanError(f"stations must be one of {list(STATION_MODES)}", field="stations", value=stations)
    if stations == "anywhere_on_top" and top is None:
        raise PlanError("anywhere_on_top needs the part's top surface", field="stations", value=stations)
    if len(nominals) == 0:
        raise PlanError("the field planner needs at least one trace", field="traces", value=0)
    paths = [as_trace_polyline(n, field=f"traces[{i}]") for i, n in enumerate(nominals)]
    prior = params.prior()
    top = top if stations == "anywhere_on_top" else None
    region = field_region(paths, prior.wavelength_mm, top) if reuse is None else \
        reuse.region(paths, prior.wavelength_mm, top)
    plan = _design(region, prior, params, stations, fixed, reuse)
    dof = partial(region_dof, prior, region.samples, region.center, params.target_error_mm / params.coverage)
    return replace(plan, dof=dof, nyquist_dof=region.nyquist_dof)   # counted when first read


MAX_REFINE_ROUNDS = 6


@dataclass(frozen=True, eq=False)
class _Designed:
    """A design over candidate sites (N,): their trace index (-1 free), arc length (NaN
    free) and nominal z; kept (n,) station indices into the sites; parts: the posterior
    over every trace sample from a fresh factorisation."""

    sites: Sites
    trace: np.ndarray
    s: np.ndarray
    z: np.ndarray
    kept: np.ndarray
    parts: PosteriorParts

    def with_samples(self, samples: TracePoints, idx: np.ndarray) -> _Designed:
        """The same design with the trace samples ``idx`` appended to the candidate sites."""
        sites = Sites(np.concatenate([self.sites.xy, samples.sites.xy[idx]]),
                      np.concatenate([self.sites.grad, samples.sites.grad[idx]]))
        return _Designed(sites, np.concatenate([self.trace, samples.trace[idx]]),
                         np.concatenate([self.s, samples.s[idx]]), np.concatenate([self.z, samples.z[idx]]),
                         self.kept, self.parts)


def _exchanged(design: _Designed, region: FieldRegion, prior: DeviationPrior, target_var: float,
               least: int) -> _Designed:
    """The exchange refinement (:mod:`app.probing.field_exchange`) of a minimal design.  Its
    result is kept only if it has fewer stations, a fresh posterior over every trace sample
    meets the target (samples still over it are repaired by the greedy) and elimination
    drops nothing more; otherwise ``design`` is returned unchanged."""
    samples = region.samples
    # the trace samples near the target join the moves' candidates (and targets): fewer repairs
    work = design.with_samples(samples, np.flatnonzero(design.parts.var > TIGHT_SAMPLE * target_var))
    trial = exchange_stations(prior, region.center, work.sites, work.trace >= 0, design.kept, target_var, least)
    for _ in range(MAX_REFINE_ROUNDS):
        if len(trial) >= len(design.kept):
            break
        fresh = posterior_parts(prior, work.sites.take(trial), samples.sites, region.center)
        if fresh.var.max() <= target_var * (1 + 1e-9):
            shorter = eliminate_redundant(fresh, target_var, least)
            if len(shorter.keep) == len(trial):
                return _Designed(work.sites, work.trace, work.s, work.z, trial, fresh)
            trial = trial[shorter.keep]
            continue
        assert fresh.weights is not None  # posterior_parts keeps them by default
        added, precision, weights, var = repair_stations(
            prior, region.center, work.sites.take(trial), samples.sites, fresh.precision, fresh.weights,
            fresh.var, target_var)
        shorter = eliminate_redundant(PosteriorParts(precision, weights, var, np.arange(len(trial) + len(added))),
                                      target_var, least)
        first = len(work.sites.xy)
        work = work.with_samples(samples, np.asarray(added, dtype=int))
        trial = np.concatenate([trial, first + np.arange(len(added))])[shorter.keep]
    return design


def _design(region: FieldRegion, prior: DeviationPrior, params: PlanParams, stations: str,
            fixed: Sites | None = None, reuse: PlanReuse | None = None) -> FieldPlan:
    """Greedy design on the thinned targets (and the free candidates); then (automatic
    count) every trace sample is checked, the ones still over the target join the sites
    (appended: the greedy's factor is extended, not rebuilt) and the greedy sequence
    continues, until every sample meets it; then backward elimination and, with
    ``params.exchange``, the exchange refinement (:func:`_exchanged`)."""
    samples = region.samples
    target_var = (params.target_error_mm / params.coverage) ** 2
    count = None if params.count is None else int(params.count)
    pool = region.targets
    if count is not None and count > len(pool) + len(region.free.xy):
        raise PlanError(f"count {count} exceeds the {len(pool) + len(region.free.xy)} candidate stations "
                        "of this board", field="count", value=count)
    # per site of the greedy's U: trace index (-1 free), arc length (NaN free), nominal z
    nf = 0 if fixed is None else len(fixed.xy)
    fixed = fixed if fixed is not None else Sites(np.zeros((0, 2)), np.zeros((0, 2)))
    site_trace = np.concatenate([np.full(nf, -2), pool.trace, np.full(len(region.free_z), -1)])
    site_s = np.concatenate([np.full(nf, np.nan), pool.s, np.full(len(region.free_z), np.nan)])
    site_z = np.concatenate([np.full(nf, np.nan), pool.z, region.free_z])
    u = Sites(np.concatenate([fixed.xy, pool.sites.xy, region.free.xy]),
              np.concatenate([fixed.grad, pool.sites.grad, region.free.grad]))

    def started() -> GreedyField:
        out = GreedyField(prior, u, region.center)
        out.add_many(np.arange(nf))  # the stations already touched come first
        return out
    stop = None if count is not None else (target_var, max(2, params.min_count))
    greedy = started() if reuse is None else reuse.start(prior, u, region.center, nf, started, stop)
    for step in range(MAX_REFINE_ROUNDS):
        greedy_sequence(greedy, np.flatnonzero(site_trace >= 0), count, target_var, max(2, params.min_count), nf)
        if reuse is not None and stop is not None and step == 0:
            reuse.stopped(prior, u, region.center, nf, stop, greedy)
        chosen = np.array(greedy.chosen)
        jinc = None if reuse is None else reuse.jinc(greedy.sites.take(chosen).xy, samples.sites, prior.wavelength_mm)
        parts = posterior_parts(prior, greedy.sites.take(chosen), samples.sites, region.center, jinc=jinc,
                                weights=count is None and nf == 0)  # the elimination's, below
        over = np.flatnonzero(parts.var > target_var * (1 + 1e-9))
        if count is not None or len(over) == 0:
            break
        greedy.extend(samples.sites.take(over))
        site_trace = np.concatenate([site_trace, samples.trace[over]])
        site_s = np.concatenate([site_s, samples.s[over]])
        site_z = np.concatenate([site_z, samples.z[over]])
    kept = chosen
    designed = _Designed(greedy.sites, site_trace, site_s, site_z, kept, parts)
    if count is None and len(over) == 0 and nf == 0:  # drop what later stations made redundant
        parts = eliminate_redundant(parts, target_var, max(2, params.min_count))
        designed = _Designed(greedy.sites, site_trace, site_s, site_z, chosen[parts.keep], parts)
        if params.exchange:
            designed = _exchanged(designed, region, prior, target_var, max(2, params.min_count))
    sites, site_trace, site_s, site_z = designed.sites, designed.trace, designed.s, designed.z
    kept, parts = designed.kept, designed.parts
    sd = np.sqrt(parts.var)
    kept = kept[nf:]  # the fixed stations were added first and are not returned
    order = travel_order(sites.xy[kept], prior.wavelength_mm / 2)
    picked = kept[order]
    station_sites = sites.take(picked)
    per_trace = np.zeros(int(samples.trace.max()) + 1)
    np.maximum.at(per_trace, samples.trace, sd)
    return FieldPlan(station_sites.xy, site_z[picked], station_sites.grad, site_trace[picked], site_s[picked],
                     region.center, float(sd.max()), per_trace, region.area_mm2, stations,
                     np.argsort(order))
