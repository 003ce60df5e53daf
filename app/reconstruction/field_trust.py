"""A fitted field checked against the part before anything is printed from it.

:func:`checked_field` fits the field of a probe run in three steps:

1. the deviation prior's amplitude, wavelength and noise are **learned** from the stations'
   touches (type-II ML, :mod:`app.reconstruction.field_learning`), the user's values being
   the start and the centre of the bounds;
2. the field is fitted with the learned prior (:func:`app.reconstruction.field.fit_field`,
   leave-one-out outlier rejection under the learned model; with an exclusion the prior is
   learned again from the kept touches);
3. the **verification points** (touched after the stations where the trace's posterior is least
   certain, never used in the fit) are predicted and compared with what was measured.

Verdict: the field is *verified* when the learned model fits (no LOO misfit), every
verification residual lies within ``coverage`` x its predictive sd (posterior sd and probe
noise) and within the bound promised for the traces, and that bound meets the target
within TARGET_SLACK (:func:`bound_meets_target`; the sequential planner adds stations until
it does, :mod:`app.reconstruction.field_sequential`).  The bound itself is reported as it is;
a plan too sparse for the part is off by far more.  The bound allows for the learned
amplitude's and wavelength's own uncertainty (they are estimates from a few dozen touches,
:func:`cautious_bounds`): with HYPER_BOUND ``"corner"`` each is taken HYPER_SD of its own sd
on its unfavourable side (:func:`cautious_prior`); ``"ellipse"`` takes the largest bound over
their joint ELLIPSE_SD-sd ellipse (:mod:`app.reconstruction.hyper_bound`).  A run's traces share
its confidence (:func:`trace_bound` ``traces``), so the run's bound holds over all of them.  A verification point
where the compensated program would be off by more than the uncompensated one
(|measured - predicted| >= |measured|, by more than the probe's noise: the correction does not
help there) flags its trace as *worse than nominal*.  Anything else is ``needs_attention`` with the reasons.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
import threading
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, TypeVar

import numpy as np
from scipy.special import ndtr, ndtri

from app.probing.deviation_prior import DeviationPosterior, DeviationPrior, Sites, fit_posterior, path_sites
from app.reconstruction.field import FieldFit, fit_field
from app.reconstruction.field_learning import MIN_TOUCHES, LearnedPrior, learn_prior
from app.reconstruction.hyper_bound import ELLIPSE_SD, METHODS, ellipse_max, log_covariance

TARGET_SLACK = 1.25  # a bound up to 25 % over the target is the plan met (see the module doc)


@dataclass(frozen=True)
class Verification:
    """Verification touches against the fitted field.

    xy (k, 2) mm; trace (k,) trace index; measured_mm (k,) measured deviation; predicted_mm
    (k,) the field's; sd_mm (k,) predictive sd (posterior and noise); limit_mm (k,) =
    coverage x sd; residual_mm = measured - predicted; within (k,) |residual| <= limit;
    noise_limit_mm: coverage x the probe noise; worse (k,) the correction does not help there
    (|residual| >= |measured|, the residual more than the noise: where the part is within a
    touch's noise of nominal, which of the two is nearer cannot be read from one touch)."""

    xy: np.ndarray
    trace: np.ndarray
    measured_mm: np.ndarray
    predicted_mm: np.ndarray
    sd_mm: np.ndarray
    limit_mm: np.ndarray
    noise_limit_mm: float = 0.0

    @property
    def residual_mm(self) -> np.ndarray:
        out: np.ndarray = self.measured_mm - self.predicted_mm
        return out

    @property
    def within(self) -> np.ndarray:
        out: np.ndarray = np.abs(self.residual_mm) <= self.limit_mm
        return out

    @property
    def worse(self) -> np.ndarray:
        r = np.abs(self.residual_mm)
        out: np.ndarray = (r >= np.abs(self.measured_mm)) & (r > self.noise_limit_mm)
        return out

    @property
    def max_abs_residual_mm(self) -> float:
        return float(np.abs(self.residual_mm).max()) if len(self.xy) else 0.0

    def arrays(self) -> dict[str, list[Any]]:
        """The fields as lists (a cache's JSON); :meth:`from_arrays` reads them back."""
        return {**{k: getattr(self, k).tolist() for k in ("xy", "trace", "measured_mm", "predicted_mm", "sd_mm",
                                                           "limit_mm")}, "noise_limit_mm": [self.noise_limit_mm]}

    @classmethod
    def from_arrays(cls, data: dict[str, list[Any]]) -> Verification:
        measured, predicted, sd, limit = (np.asarray(data[k], dtype=float)
                                          for k in ("measured_mm", "predicted_mm", "sd_mm", "limit_mm"))
        return cls(np.asarray(data["xy"], dtype=float).reshape(-1, 2), np.asarray(data["trace"], dtype=int),
                   measured, predicted, sd, limit, float(data.get("noise_limit_mm", [0.0])[0]))


def joint_coverage(coverage: float, count: int) -> float:
    """The per-point limit in sd for ``count`` points tested together at the confidence
    ``coverage`` gives one point (Bonferroni: the false alarms of all of them together at
    2 Phi(-coverage), so a model that holds asks for attention as rarely as one point would)."""
    return -float(ndtri(ndtr(-coverage) / max(count, 1)))  # the normal's upper tail and its quantile


def verify(fit: FieldFit, sites: Sites, measured_mm: np.ndarray, trace: np.ndarray, coverage: float) -> Verification:
    """The field ``fit`` at verification sites (k,) against deviations measured there; each
    point's limit is :func:`joint_coverage` x its predictive sd (posterior and probe noise)."""
    predicted = fit.deviation(sites)
    sd = np.sqrt(fit.posterior.sd(sites) ** 2 + fit.posterior.prior.sigma_mm ** 2)
    return Verification(sites.xy, np.asarray(trace, dtype=int), np.asarray(measured_mm, dtype=float), predicted,
                        sd, joint_coverage(coverage, len(sd)) * sd, coverage * fit.posterior.prior.sigma_mm)


@dataclass(frozen=True)
class FieldCheck:
    """The checked field of one probe run.

    fit: the field (fitted with the learned prior); learned: the learning's JSON form
    (:meth:`LearnedPrior.as_dict`; None below MIN_TOUCHES stations: the user's prior is used); verification (None
    without points); coverage, target_mm: the promise (coverage x sd <= target); bound_mm: the largest of the
    traces' bounds under the fitted model (:func:`trace_bound`: over each whole trace, at the
    confidence ``coverage`` gives one point; set by the caller, who has the traces; NaN until
    then)."""

    fit: FieldFit
    learned: dict[str, Any] | None
    verification: Verification | None
    coverage: float
    target_mm: float
    bound_mm: float = math.nan

    @property
    def worse_traces(self) -> tuple[int, ...]:
        v = self.verification
        return () if v is None else tuple(sorted({int(t) for t, w in zip(v.trace, v.worse) if w and t >= 0}))

    @property
    def reasons(self) -> tuple[str, ...]:
        out: list[str] = []
        if self.learned is not None and self.learned["loo"]["misfit"]:
            out += [f"the field model misfits the touches: {r}" for r in self.learned["loo"]["reasons"]]
        v = self.verification
        if v is not None and not v.within.all():
            i = int(np.argmax(np.abs(v.residual_mm) / v.limit_mm))
            out.append(f"{int((~v.within).sum())} of {len(v.xy)} verification points off the field by more than "
                       f"{joint_coverage(self.coverage, len(v.xy)):.2f} sd (worst {v.residual_mm[i] * 1000:+.1f} um at "
                       f"[{v.xy[i, 0]:.2f}, {v.xy[i, 1]:.2f}] mm, limit {v.limit_mm[i] * 1000:.1f} um)")
        if v is not None and len(v.xy) and v.max_abs_residual_mm > self.measured_bound_mm:
            out.append(f"a verification point is off the field by {v.max_abs_residual_mm * 1000:.1f} um, more than the "
                       f"bound {self.bound_mm * 1000:.1f} um promised for the traces (with the probe's noise "
                       f"{self.measured_bound_mm * 1000:.1f} um)")
        if self.worse_traces:
            out.append(f"the correction makes trace(s) {list(self.worse_traces)} worse than the nominal program at a "
                       "verification point")
        if not bound_meets_target(self.bound_mm, self.target_mm):
            out.append(f"under the fitted model the traces are known to {self.bound_mm * 1000:.1f} um, over the "
                       f"target {self.target_mm * 1000:.1f} um by more than {TARGET_SLACK - 1:.0%}: add stations "
                       "(plan with the fitted prior)")
        return tuple(out)

    @property
    def noise_allowance_mm(self) -> float:
        """``coverage`` x the probe noise: what a touch reads on top of the field's error."""
        return float(self.coverage * self.fit.posterior.prior.sigma_mm)

    @property
    def measured_bound_mm(self) -> float:
        """What a touch may read off the field where the bound holds (:func:`measured_bound`)."""
        return measured_bound(self.bound_mm, self.noise_allowance_mm)

    @property
    def needs_attention(self) -> bool:
        return bool(self.reasons)

    def verified_line(self) -> str:
        """'verified at K points: max |residual| X um (bound Y um)', or 'NOT verified at K
        points: ... worst at [x, y] mm' when a point is outside its band or over the bound."""
        v = self.verification
        if v is None or not len(v.xy):
            return "not verified: no verification points were touched"
        return verification_line([{"xy": xy.tolist(), "residual_mm": float(r), "within": bool(w)}
                                  for xy, r, w in zip(v.xy, v.residual_mm, v.within)], self.bound_mm,
                                 self.noise_allowance_mm)

    def as_dict(self) -> dict[str, Any]:
        """JSON form for job results and the run report."""
        fit = self.fit
        out: dict[str, Any] = {
            "needs_attention": self.needs_attention, "reasons": list(self.reasons),
            "verified": self.verified_line(), "coverage": self.coverage, "target_mm": self.target_mm,
            "bound_mm": None if not math.isfinite(self.bound_mm) else self.bound_mm,
            "noise_allowance_mm": self.noise_allowance_mm,
            "prior_used": {k: float(getattr(fit.posterior.prior, k))
                           for k in ("amplitude_mm", "wavelength_mm", "sigma_mm")},
            "learned": self.learned,
            "worse_traces": list(self.worse_traces),
            "exclusions": [{"station": int(i), "xy": fit.stations.xy[i].tolist(), "trace": int(fit.trace[i]),
                            "deviation_mm": float(fit.dz[i]),
                            "residual_mm": float(fit.dz[i] - fit.deviation(fit.stations.take(np.array([i])))[0])}
                           for i in fit.outliers],
        }
        v = self.verification
        if v is not None:
            out["verification"] = [
                {"xy": xy.tolist(), "trace": int(t), "measured_mm": float(m), "predicted_mm": float(p),
                 "residual_mm": float(m - p), "limit_mm": float(lim), "within": bool(w), "worse": bool(b)}
                for xy, t, m, p, lim, w, b in zip(v.xy, v.trace, v.measured_mm, v.predicted_mm, v.limit_mm,
                                                  v.within, v.worse)]
        return out


def measured_bound(bound_mm: float | None, noise_allowance_mm: float = 0.0) -> float:
    """What a touch may read off the field where the field's error is within ``bound_mm``:
    the bound and the touch's own noise allowance (coverage x probe sd) in quadrature (NaN
    without a bound)."""
    return math.nan if bound_mm is None else math.hypot(float(bound_mm), noise_allowance_mm)


def verification_line(points: Sequence[dict[str, Any]], bound_mm: float | None,
                      noise_allowance_mm: float = 0.0) -> str:
    """The verdict line of verification points (each with ``xy``, ``residual_mm``, ``within``)
    against the ``bound_mm`` promised for the traces: 'verified at K points: max |residual| X
    um (bound Y um)' when every residual is within its band and the bound (with the touch's
    ``noise_allowance_mm``, :func:`measured_bound`), else 'NOT verified at K points: ...,
    worst at [x, y] mm' (where to look: a step shows there)."""
    if not points:
        return "not verified: no verification points were touched"
    worst = max(points, key=lambda p: abs(p["residual_mm"]))
    top = abs(worst["residual_mm"])
    bound = math.nan if bound_mm is None else float(bound_mm)
    ok = all(p["within"] for p in points) and not top > measured_bound(bound_mm, noise_allowance_mm)
    said = f"bound {bound * 1000:.1f} um" if math.isfinite(bound) else "no bound"
    line = (f"{'verified' if ok else 'NOT verified'} at {len(points)} points: "
            f"max |residual| {top * 1000:.1f} um ({said})")
    if not ok:
        outside = max((p for p in points if not p["within"]), key=lambda p: abs(p["residual_mm"]), default=worst)
        line += f", worst at [{outside['xy'][0]:.2f}, {outside['xy'][1]:.2f}] mm"
    return line


def checked_field(prior: DeviationPrior, stations: Sites, nominal_z: np.ndarray, measured: np.ndarray,
                  center: np.ndarray, trace: np.ndarray, s_mm: np.ndarray, verify_mask: np.ndarray,
                  coverage: float, target_mm: float, learn: bool = True,
                  field: str = "points", learned_first: LearnedPrior | None = None) -> FieldCheck:
    """Learn, fit and verify the field of one run (see the module doc).

    stations (n,) every touched point of the plan (stations and verification points, the
    latter marked by ``verify_mask`` (n,) bool); nominal_z (n,), measured (n, 3) mm in the
    same order; trace / s_mm (n,) as for :func:`fit_field`.  ``learned_first``: the caller's
    own :func:`learn_prior` of ``prior`` over the same fit stations and deviations (it is
    the first learning here, not repeated)."""
    mask = np.asarray(verify_mask, dtype=bool)
    keep = np.flatnonzero(~mask)
    pts = np.asarray(measured, dtype=float)
    nominal = np.asarray(nominal_z, dtype=float)
    fit_sites = stations.take(keep)

    def fitted(p: DeviationPrior) -> FieldFit:
        return fit_field(p, fit_sites, nominal[keep], pts[keep], center, trace[keep], s_mm[keep], field=field)

    learned = None
    if learn and len(keep) >= MIN_TOUCHES:
        dz = pts[keep, 2] - nominal[keep]
        learned = learned_first or learn_prior(prior, fit_sites, dz, center)
        fit = fitted(learned.prior)
        if fit.outliers:
            kept = fit.kept
            relearned = learn_prior(prior, fit_sites.take(np.flatnonzero(kept)), dz[kept], center)
            if relearned.prior != learned.prior:
                learned = relearned
                fit = fitted(learned.prior)
    else:
        fit = fitted(prior)
    verification = None
    if mask.any():
        idx = np.flatnonzero(mask)
        verification = verify(fit, stations.take(idx), pts[idx, 2] - nominal[idx], trace[idx], coverage)
    return FieldCheck(fit, None if learned is None else learned.as_dict(), verification, coverage, target_mm)


BOUND_STEP_PER_WAVELENGTH = 16  # a trace's posterior sd judged every lambda / 16 (as the planner does)


HYPER_SD = 2.0  # the bound is taken with the learned amplitude and wavelength this many sd on their unfavourable side


def _learned_log_sd(learned: dict[str, Any], name: str) -> float:
    """The sd of the log of ``learned``'s parameter ``name`` (:meth:`LearnedPrior.as_dict`), NaN
    where it has none (on a bound)."""
    rel = learned.get(name, {}).get("relative_sd")
    return math.nan if rel is None or not math.isfinite(rel) else math.log1p(float(rel))


def cautious_prior(prior: DeviationPrior, learned: dict[str, Any] | None) -> DeviationPrior:
    """The fitted ``prior`` with its amplitude HYPER_SD relative sd larger and its wavelength
    HYPER_SD relative sd shorter (the Laplace sd of ``learned``, :meth:`LearnedPrior.as_dict`;
    a parameter on a bound, or no learning, is taken as it is).  The learned values are
    estimates from a few dozen touches (their sd is 5-30 %): a bound under the point estimate
    alone is too short as often as the amplitude is underestimated.  Shorter and larger both
    widen the posterior between stations; where the noise dominates they change little."""
    if learned is None:
        return prior

    def log_sd(name: str) -> float:
        sd = _learned_log_sd(learned, name)
        return sd if math.isfinite(sd) else 0.0
    return replace(prior, amplitude_mm=prior.amplitude_mm * math.exp(HYPER_SD * log_sd("amplitude_mm")),
                   wavelength_mm=prior.wavelength_mm * math.exp(-HYPER_SD * log_sd("wavelength_mm")))


HYPER_BOUND = "corner"  # how a bound allows for the hyperparameters' uncertainty (hyper_bound.METHODS)


def cautious_bounds(bound_of: Callable[[DeviationPrior], np.ndarray], prior: DeviationPrior,
                    learned: dict[str, Any] | None, method: str | None = None) -> np.ndarray:
    """Bounds (T,) mm under the learned ``prior`` allowing for its amplitude's and wavelength's
    uncertainty (``learned``: :meth:`LearnedPrior.as_dict`), ``bound_of(prior) -> (T,)`` mm
    the bounds under a given prior: ``method`` (default HYPER_BOUND) ``"corner"``, under
    :func:`cautious_prior`; ``"ellipse"``, each the largest over the joint ELLIPSE_SD-sd ellipse
    of (log A, log lambda) (:func:`app.reconstruction.hyper_bound.ellipse_max`; the corner
    where ``learned`` carries no correlation)."""
    method = HYPER_BOUND if method is None else method
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: one of {METHODS}")
    if method == "corner" or learned is None or "amplitude_wavelength_correlation" not in learned:
        return np.asarray(bound_of(cautious_prior(prior, learned)), dtype=float)
    rho = learned["amplitude_wavelength_correlation"]
    cov = log_covariance((_learned_log_sd(learned, "amplitude_mm"), _learned_log_sd(learned, "wavelength_mm")),
                         math.nan if rho is None else float(rho))

    def at(d: np.ndarray) -> np.ndarray:
        return np.asarray(bound_of(replace(prior, amplitude_mm=prior.amplitude_mm * math.exp(d[0]),
                                           wavelength_mm=prior.wavelength_mm * math.exp(d[1]))), dtype=float)
    return ellipse_max(at, cov, ELLIPSE_SD)


_BOUND_POSTERIORS: weakref.WeakKeyDictionary[FieldFit, dict[DeviationPrior, DeviationPosterior]] = \
    weakref.WeakKeyDictionary()
_BOUND_POSTERIORS_LOCK = threading.Lock()


def bound_posterior(fit: FieldFit, learned: dict[str, Any] | None) -> DeviationPosterior:
    """The posterior of the fit's kept touches under :func:`cautious_prior` (:func:`posterior_under`)."""
    return posterior_under(fit, cautious_prior(fit.posterior.prior, learned))


def posterior_under(fit: FieldFit, prior: DeviationPrior) -> DeviationPosterior:
    """The posterior of the fit's kept touches under ``prior`` (its sd is what a bound is built
    from; the field itself stays the fit's).  Factorised once per fit and prior (kept while the
    fit lives): every trace of a run asks for the same one."""
    if prior == fit.posterior.prior:
        return fit.posterior
    with _BOUND_POSTERIORS_LOCK:
        known = _BOUND_POSTERIORS.get(fit, {}).get(prior)
    if known is not None:
        return known
    posterior = fit_posterior(prior, fit.stations.take(np.flatnonzero(fit.kept)), fit.dz[fit.kept],
                              fit.posterior.center)
    with _BOUND_POSTERIORS_LOCK:
        _BOUND_POSTERIORS.setdefault(fit, {})[prior] = posterior
    return posterior


NEWTON_STEPS = 100  # at most (Newton converges quadratically: a trace stops after a handful)


def simultaneous_bound(sd_mm: np.ndarray, step_mm: float, wavelength_mm: float, coverage: float,
                       traces: int = 1) -> float:
    """The bound u (mm) on |model - truth| over a whole trace whose posterior sd, sampled every
    ``step_mm``, is ``sd_mm`` (m,): the union bound at the confidence ``coverage`` gives one
    point (1 - 2 Phi(-coverage)) over the error's independent values.  The field is
    band-limited at ``wavelength_mm`` and so is its posterior error: one independent value per
    half wavelength, each sample standing for step / (wavelength / 2) of one.  Solves
    sum_i w 2 Phi(-u / sd_i) = 2 Phi(-coverage) / traces, w = min(1, 2 step / wavelength);
    never below coverage x max sd (one point's bound).  ``traces``: the traces of the run that
    share the confidence (each gets 1 / traces of it: the largest of their bounds then holds
    for the whole run at the confidence ``coverage`` gives one point)."""
    sd = np.asarray(sd_mm, dtype=float)
    return float(simultaneous_bounds(sd, np.array([0, len(sd)]), np.array([step_mm]), wavelength_mm, coverage,
                                     traces)[0])


def simultaneous_bounds(sd_mm: np.ndarray, edges: np.ndarray, step_mm: np.ndarray, wavelength_mm: float,
                        coverage: float, traces: int = 1) -> np.ndarray:
    """:func:`simultaneous_bound` of T traces at once, (T,) mm: trace t's sd samples are
    ``sd_mm[edges[t]:edges[t + 1]]`` (edges (T + 1,), each trace at least one sample), sampled
    every ``step_mm[t]`` (T,).  Each equation f(u) = 0 is convex and decreasing in u, and
    f > 0 at one point's bound (else that is the bound): Newton's steps from there rise to the
    root without passing it, and a trace stops when its f is no longer positive or its step
    no longer moves it (at most NEWTON_STEPS; every trace on its own, so a trace's bound is
    the same number whichever traces share the solve)."""
    sd = np.maximum(np.asarray(sd_mm, dtype=float), 1e-12)
    starts = np.asarray(edges[:-1], dtype=np.intp)
    owner = np.repeat(np.arange(len(starts)), np.diff(edges))
    alpha = 2.0 * float(ndtr(-coverage)) / max(int(traces), 1)
    weight = np.minimum(1.0, 2.0 * np.asarray(step_mm, dtype=float) / wavelength_mm)
    u = coverage * np.maximum.reduceat(sd, starts)
    active = np.ones(len(u), dtype=bool)
    for _ in range(NEWTON_STEPS):
        z = u[owner] / sd
        f = weight * np.add.reduceat(2.0 * ndtr(-z), starts) - alpha
        slope = -weight * np.add.reduceat(2.0 * np.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * sd), starts)
        active &= (f > 0.0) & (slope < 0.0)
        step = np.where(active, f / np.where(active, -slope, 1.0), 0.0)
        active &= u + step > u
        if not active.any():
            break
        u = np.where(active, u + step, u)
    return u


def trace_bound(fit: FieldFit, path: Any, coverage: float, learned: dict[str, Any] | None = None,
                traces: int = 1) -> float:
    """The bound (mm) on the fitted field's error over the whole trace ``path`` (a
    TracePolyline) under the fitted model: :func:`simultaneous_bound` of its posterior sd
    every wavelength / BOUND_STEP_PER_WAVELENGTH of arc length; with ``learned`` (the
    learning's JSON form) allowing for the hyperparameters' own uncertainty (:func:`cautious_bounds`;
    on the ellipse a trace alone finds the worst point by its own bound, a run by its largest);
    ``traces``: how many traces of the run share the confidence (the run's bound, the largest
    trace bound, then holds over every trace together)."""
    return float(cautious_bounds(lambda p: np.array(posterior_trace_bounds(posterior_under(fit, p), [path], coverage,
                                                                           traces)),
                                 fit.posterior.prior, learned)[0])


def trace_bounds(fit: FieldFit, paths: Sequence[Any], coverage: float, learned: dict[str, Any] | None = None,
                 traces: int = 1) -> np.ndarray:
    """:func:`trace_bound` of each TracePolyline of ``paths`` (T,) mm, each on its own: one
    batched solve when the bound's prior is every trace's (the corner, or no correlation
    learned; equal to rounding, ~1e-14 mm), else (the ellipse: each trace's own worst point) one by one."""
    if HYPER_BOUND != "corner" and learned is not None and "amplitude_wavelength_correlation" in learned:
        return np.array([trace_bound(fit, path, coverage, learned, traces) for path in paths])
    posterior = posterior_under(fit, cautious_prior(fit.posterior.prior, learned))
    return np.array(posterior_trace_bounds(posterior, paths, coverage, traces))


SD_BATCH = 4096  # trace points whose posterior sd is computed in one solve
# per path: (count, arc lengths (count,), their Sites) at the last count asked
_BOUND_SITES: weakref.WeakKeyDictionary[Any, tuple[int, np.ndarray, Sites]] = weakref.WeakKeyDictionary()


def _bound_samples(path: Any, wavelength_mm: float) -> tuple[np.ndarray, Sites]:
    """(arc lengths (m,) mm, their Sites) where a trace's sd is judged: every wavelength /
    BOUND_STEP_PER_WAVELENGTH, both ends included.  The last count's are kept per path (the
    forecasts of one round ask at close wavelengths, most traces at the same count)."""
    count = max(2, int(np.ceil(path.length_mm / (wavelength_mm / BOUND_STEP_PER_WAVELENGTH))) + 1)
    kept = _BOUND_SITES.get(path)
    if kept is not None and kept[0] == count:
        return kept[1], kept[2]
    s = np.linspace(0.0, path.length_mm, count)
    sites = path_sites(path, s)
    for a in (s, sites.xy, sites.grad):
        a.setflags(write=False)
    _BOUND_SITES[path] = (count, s, sites)
    return s, sites


def posterior_trace_bounds(posterior: DeviationPosterior, paths: Sequence[Any], coverage: float,
                           traces: int | None = None) -> tuple[float, ...]:
    """The bound (mm) over each TracePolyline of ``paths`` (T,) under ``posterior`` (:func:`trace_bound`), the
    traces' points batched into SD_BATCH-point solves; ``traces``: how many share the confidence (default T)."""
    wavelength = posterior.prior.wavelength_mm
    samples, sites = zip(*(_bound_samples(p, wavelength) for p in paths))
    sd = np.empty(sum(len(s) for s in samples))
    xy, grad = np.concatenate([q.xy for q in sites]), np.concatenate([q.grad for q in sites])
    for start in range(0, len(sd), SD_BATCH):
        stop = start + SD_BATCH
        sd[start:stop] = posterior.sd(Sites(xy[start:stop], grad[start:stop]))
    edges = np.cumsum([0] + [len(s) for s in samples])
    shared = len(paths) if traces is None else traces
    steps = np.array([p.length_mm / (len(s) - 1) for p, s in zip(paths, samples)])
    return tuple(float(u) for u in simultaneous_bounds(sd, edges, steps, wavelength, coverage, shared))


def bound_meets_target(bound_mm: float, target_mm: float) -> bool:
    """The verdict's test of a run's bound: within TARGET_SLACK x the target (a NaN bound, not
    yet computed, passes: the caller has no traces)."""
    return not bound_mm > target_mm * TARGET_SLACK


def run_bounds(check: FieldCheck, paths: Sequence[Any]) -> tuple[float, ...]:
    """Each trace's bound (T,) mm (:func:`trace_bound`) over the run's T traces ``paths``
    (TracePolylines), the T sharing the confidence: the largest is the run's bound."""
    def bounds(prior: DeviationPrior) -> np.ndarray:
        return np.array(posterior_trace_bounds(posterior_under(check.fit, prior), paths, check.coverage))
    return tuple(float(u) for u in cautious_bounds(bounds, check.fit.posterior.prior, check.learned))


_Check = TypeVar("_Check", bound=FieldCheck)


def with_bound(check: _Check, trace_bounds_mm: Sequence[float] | np.ndarray) -> _Check:
    """``check`` with its bound: the largest of the traces' bounds (T,) mm (:func:`trace_bound`)."""
    return replace(check, bound_mm=float(np.max(trace_bounds_mm)))
