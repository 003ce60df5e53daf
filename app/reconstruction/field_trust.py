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
noise) and within the bound promised for the traces, and that bound meets the target.  A verification point
where the compensated program would be off by more than the uncompensated one
(|measured - predicted| >= |measured|: the correction does not help there) flags its trace as
*worse than nominal*.  Anything else is ``needs_attention`` with the reasons.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from app.probing.deviation_prior import DeviationPrior, Sites
from app.reconstruction.field import FieldFit, fit_field
from app.reconstruction.field_learning import MIN_TOUCHES, learn_prior


@dataclass(frozen=True)
class Verification:
    """Verification touches against the fitted field.

    xy (k, 2) mm; trace (k,) trace index; measured_mm (k,) measured deviation; predicted_mm
    (k,) the field's; sd_mm (k,) predictive sd (posterior and noise); limit_mm (k,) =
    coverage x sd; residual_mm = measured - predicted; within (k,) |residual| <= limit;
    worse (k,) the correction does not help there (|residual| >= |measured|)."""

    xy: np.ndarray
    trace: np.ndarray
    measured_mm: np.ndarray
    predicted_mm: np.ndarray
    sd_mm: np.ndarray
    limit_mm: np.ndarray

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
        out: np.ndarray = np.abs(self.residual_mm) >= np.abs(self.measured_mm)
        return out

    @property
    def max_abs_residual_mm(self) -> float:
        return float(np.abs(self.residual_mm).max()) if len(self.xy) else 0.0

    def arrays(self) -> dict[str, list[Any]]:
        """The fields as lists (a cache's JSON); :meth:`from_arrays` reads them back."""
        return {k: getattr(self, k).tolist() for k in ("xy", "trace", "measured_mm", "predicted_mm", "sd_mm",
                                                        "limit_mm")}

    @classmethod
    def from_arrays(cls, data: dict[str, list[Any]]) -> "Verification":
        return cls(np.asarray(data["xy"], dtype=float).reshape(-1, 2), np.asarray(data["trace"], dtype=int),
                   *(np.asarray(data[k], dtype=float) for k in ("measured_mm", "predicted_mm", "sd_mm", "limit_mm")))


def verify(fit: FieldFit, sites: Sites, measured_mm: np.ndarray, trace: np.ndarray, coverage: float) -> Verification:
    """The field ``fit`` at verification sites (k,) against deviations measured there."""
    predicted = fit.deviation(sites)
    sd = np.sqrt(fit.posterior.sd(sites) ** 2 + fit.posterior.prior.sigma_mm ** 2)
    return Verification(sites.xy, np.asarray(trace, dtype=int), np.asarray(measured_mm, dtype=float), predicted,
                        sd, coverage * sd)


@dataclass(frozen=True)
class FieldCheck:
    """The checked field of one probe run.

    fit: the field (fitted with the learned prior); learned: the learning's JSON form
    (:meth:`LearnedPrior.as_dict`; None below MIN_TOUCHES stations: the user's prior is used); verification (None without points);
    coverage, target_mm: the promise (coverage x sd <= target); bound_mm: coverage x the
    largest posterior sd over the traces under the fitted model (set by the caller, who
    has the traces; NaN until then)."""

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
                       f"{self.coverage:g} sd (worst {v.residual_mm[i] * 1000:+.1f} um at "
                       f"[{v.xy[i, 0]:.2f}, {v.xy[i, 1]:.2f}] mm, limit {v.limit_mm[i] * 1000:.1f} um)")
        if v is not None and len(v.xy) and math.isfinite(self.bound_mm) and v.max_abs_residual_mm > self.bound_mm:
            out.append(f"a verification point is off the field by {v.max_abs_residual_mm * 1000:.1f} um, more than the "
                       f"bound {self.bound_mm * 1000:.1f} um promised for the traces")
        if self.worse_traces:
            out.append(f"the correction makes trace(s) {list(self.worse_traces)} worse than the nominal program at a "
                       "verification point")
        if math.isfinite(self.bound_mm) and self.bound_mm > self.target_mm * (1 + 1e-6):
            out.append(f"under the fitted model the traces are known to {self.bound_mm * 1000:.1f} um, over the "
                       f"target {self.target_mm * 1000:.1f} um: add stations (plan with the fitted prior)")
        return tuple(out)

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
                                  for xy, r, w in zip(v.xy, v.residual_mm, v.within)], self.bound_mm)

    def as_dict(self) -> dict[str, Any]:
        """JSON form for job results and the run report."""
        fit = self.fit
        out: dict[str, Any] = {
            "needs_attention": self.needs_attention, "reasons": list(self.reasons),
            "verified": self.verified_line(), "coverage": self.coverage, "target_mm": self.target_mm,
            "bound_mm": None if not math.isfinite(self.bound_mm) else self.bound_mm,
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


def verification_line(points: Sequence[dict[str, Any]], bound_mm: float | None) -> str:
    """The verdict line of verification points (each with ``xy``, ``residual_mm``, ``within``)
    against the ``bound_mm`` promised for the traces: 'verified at K points: max |residual| X
    um (bound Y um)' when every residual is within its band and the bound, else 'NOT
    verified at K points: ..., worst at [x, y] mm' (where to look: a step shows there)."""
    if not points:
        return "not verified: no verification points were touched"
    worst = max(points, key=lambda p: abs(p["residual_mm"]))
    top = abs(worst["residual_mm"])
    bound = math.nan if bound_mm is None else float(bound_mm)
    ok = all(p["within"] for p in points) and not top > bound
    said = f"bound {bound * 1000:.1f} um" if math.isfinite(bound) else "no bound"
    line = f"{'verified' if ok else 'NOT verified'} at {len(points)} points: max |residual| {top * 1000:.1f} um ({said})"
    if not ok:
        outside = max((p for p in points if not p["within"]), key=lambda p: abs(p["residual_mm"]), default=worst)
        line += f", worst at [{outside['xy'][0]:.2f}, {outside['xy'][1]:.2f}] mm"
    return line


def checked_field(prior: DeviationPrior, stations: Sites, nominal_z: np.ndarray, measured: np.ndarray,
                  center: np.ndarray, trace: np.ndarray, s_mm: np.ndarray, verify_mask: np.ndarray,
                  coverage: float, target_mm: float, learn: bool = True,
                  field: str = "points") -> FieldCheck:
    """Learn, fit and verify the field of one run (see the module doc).

    stations (n,) every touched point of the plan (stations and verification points, the
    latter marked by ``verify_mask`` (n,) bool); nominal_z (n,), measured (n, 3) mm in the
    same order; trace / s_mm (n,) as for :func:`fit_field`."""
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
        learned = learn_prior(prior, fit_sites, dz, center)
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


def with_bound(check: FieldCheck, trace_sd_mm: Sequence[float] | np.ndarray) -> FieldCheck:
    """``check`` with its bound: coverage x the largest of the traces' posterior sd (T,) mm."""
    return replace(check, bound_mm=float(check.coverage * np.max(trace_sd_mm)))
