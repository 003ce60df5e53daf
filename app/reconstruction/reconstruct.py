"""Reconstruct the real trace from probe points (job ``reconstruct``).

Methods:

``"interpolate"`` — the height-compensation paper's eqs. 2-3: inverse cubic NURBS interpolation through the
    measured points (clamped averaged knots, chord-length parameters, all weights 1) via
    ``app.geometry.fitting.interpolate_curve``.  Passes through every point; carries the
    probe noise into the curve.
``"approximate"`` — noise-aware 3-D alternative: a smoothing spline whose residual sum
    of squares matches the probe's sigma (``smooth_curve``).
``"deviation"`` — Conforma's model: real = nominal (exact, from CAD) + dz(s), with dz a
    cubic spline in arc length through the deviation samples (a smoothing spline with
    s = n sigma^2 when sigma > 0).  The probes only carry the small smooth deviation, so
    far fewer of them give the same accuracy (see tests/bench/test_bench_probing.py).
``"kriging"`` — the best model when the nominal has normals: dz is the posterior mean
    of a Gaussian process, band-limited machining error + the part's rigid placement
    error through the CAD slopes (``app.probing.deviation_prior``), given the probes and
    their sigma.  State the process in ``ReconstructParams.prior`` (the planner's
    ``PlanParams.prior()``); pair it with ``plan_probes(..., "kriging")``, or, for
    several traces of one part, with ``plan_joint`` and pass the other traces' probes as
    ``context`` (one posterior over the part).

Every result gives the real surface height along the trace, ``height_at_s`` /
``height_at_xy``, for compensation.  Heights from the curve methods are read where the
curve's top view passes closest to the query point.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline, make_splrep

from app.geometry.errors import GeometryError
from app.geometry.fitting import interpolate_curve, smooth_curve
from app.geometry.nurbs import NurbsCurve
from app.geometry.tolerance import DEGENERATE_LENGTH_MM
from app.geometry.traces import TracePolyline, as_trace_polyline
from app.probing.deviation_prior import DeviationPrior, Sites, fit_posterior, path_center, path_gradient
from app.probing.joint import joint_center
from app.probing.selection import chord_height_select
from app.reconstruction.heights import CurveHeight, HeightModel, KrigingHeight, SplineHeight
from app.reconstruction.preprocess import CleanPoints, PreprocessParams, ReconstructionError, preprocess

METHODS: tuple[str, ...] = ("interpolate", "approximate", "deviation", "kriging")


@dataclass(frozen=True)
class ReconstructParams:
    """Reconstruction settings (mm).  ``preprocess`` holds sigma and outlier settings.

    degree: curve degree (the seed: 3).  cl_tolerance_mm: chordal tolerance of the nominal
    points the "deviation" result curve is built on.  samples_step_mm: spacing of the
    dense deviation profile.  prior: the "kriging" model's deviation prior (its
    sigma_mm is replaced by the preprocessing sigma).
    """

    degree: int = 3
    cl_tolerance_mm: float = 0.001
    profile_step_mm: float = 0.5
    preprocess: PreprocessParams = field(default_factory=PreprocessParams)
    prior: DeviationPrior = field(default_factory=DeviationPrior)


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """The real trace.

    method: name.  curve: NurbsCurve (3-D, mm) of the real trace.  clean: the preprocessed
    measurement.  samples: (n, 2) [s_mm, dz_mm] measured minus nominal at each kept point.
    max_mm / rms_mm: max |dz| and rms dz of the samples.
    span_mm: (s0, s1) the stretch of the trace the model's heights stand for: the kept
    probes' span; for "kriging" that span widened by a quarter of the prior's shortest
    wavelength on each side (within the trace) — a band-limited deviation cannot turn
    within lambda / 4, and the posterior there is conditioned on the part's probes (the
    probing bench measures the error over the whole trace).
    """

    method: str
    curve: NurbsCurve
    clean: CleanPoints
    samples: np.ndarray
    max_mm: float
    rms_mm: float
    nominal: TracePolyline
    _height_s: HeightModel
    span_mm: tuple[float, float] = (0.0, 0.0)
    refinement: dict[str, Any] | None = None

    def height_at_s(self, s: Any) -> np.ndarray:
        """Real surface height (m,) mm along the trace at nominal arc lengths ``s`` (m,)."""
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.nominal.length_mm)
        return self._height_s(s)

    @property
    def height_model(self) -> HeightModel:
        """The height along the trace as data (:mod:`app.reconstruction.heights`)."""
        return self._height_s

    def height_at_xy(self, xy: Any) -> np.ndarray:
        """Real height (m,) mm at top-view points ``xy`` (m, 2) on (or next to) the trace."""
        return self.height_at_s(self.nominal.project_xy(np.atleast_2d(xy)).s)

    def deviation_at_s(self, s: Any) -> np.ndarray:
        """Reconstructed deviation real - nominal (m,) mm at arc lengths ``s``."""
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.nominal.length_mm)
        out: np.ndarray = self.height_at_s(s) - self.nominal.z_at(s)
        return out

    def to_result(self) -> dict[str, Any]:
        """API form: ``{method, curve, deviation: {max_mm, rms_mm, samples}, ...}``."""
        return {
            "method": self.method,
            "curve": self.curve.to_dict(),
            "deviation": {"max_mm": self.max_mm, "rms_mm": self.rms_mm,
                          "samples": [[float(a), float(b)] for a, b in self.samples]},
            "points_used": int(len(self.clean.s)),
            "outliers": list(self.clean.outliers),
            "merged_duplicates": self.clean.merged,
            **({} if self.refinement is None else {"normal_iteration": self.refinement}),
        }

    def deviation_gradient_xy(self, xy: Any, step_mm: float = 0.05) -> np.ndarray:
        """Top-view gradient (m, 2) of the reconstructed deviation at points ``xy`` (m, 2) mm
        on the trace: the along-trace derivative d dev / ds (central difference over
        ``step_mm``) along the trace's top-view direction, d dev / d s_xy = (d dev / ds) /
        |t_xy| with t the 3-D unit tangent; the across-trace part is taken as zero (the
        surface's across slope is the nominal's)."""
        s = self.nominal.project_xy(np.atleast_2d(np.asarray(xy, dtype=float))).s
        lo = np.clip(s - step_mm, 0.0, self.nominal.length_mm)
        hi = np.clip(s + step_mm, 0.0, self.nominal.length_mm)
        ds = np.maximum(hi - lo, DEGENERATE_LENGTH_MM)
        slope = (self.deviation_at_s(hi) - self.deviation_at_s(lo)) / ds
        tangent = (self.nominal.at(hi) - self.nominal.at(lo)) / ds[:, None]
        txy = tangent[:, :2]
        norm2 = np.maximum(np.sum(txy * txy, axis=1), 1e-12)
        out: np.ndarray = slope[:, None] * txy / norm2[:, None]
        return out


def fit_deviation(s: np.ndarray, dz: np.ndarray, sigma_mm: float, degree: int = 3) -> BSpline:
    """Spline dz(s) (scipy BSpline) through (n,) samples: interpolating when sigma = 0 or
    n <= degree + 1, else the smoothing spline with residual sum n * sigma^2."""
    k = int(min(degree, len(s) - 1))
    if sigma_mm <= 0 or len(s) <= degree + 1:
        return make_interp_spline(s, dz, k=k)
    return make_splrep(s, dz, k=k, s=len(s) * sigma_mm ** 2)


def reconstruct(nominal: Any, measured: Any, method: str = "interpolate",
                sigma_mm: float | None = None,
                params: ReconstructParams | None = None,
                context: Sequence[tuple[Any, Any]] = ()) -> Reconstruction:
    """Reconstruct the real trace from measured probe points.

    nominal: TracePolyline / ``.points`` (k, 3) / (k, 3) dense nominal polyline (mm).
    measured: (m, 3) probe results (mm), any order.  method: "interpolate" (seed),
    "approximate", "deviation" or "kriging".  sigma_mm overrides
    ``params.preprocess.sigma_mm``.  context ("kriging" only): (nominal, measured) pairs
    of OTHER traces of the same part, in the same frame; their probes (cleaned against
    their own nominals) join this trace's in one posterior over the part (see
    :func:`app.probing.joint.plan_joint`).  The result's samples and statistics stay this
    trace's own.
    Raises ReconstructionError (422) for bad input (NaN, too few points, off-trace).
    """
    params = params or ReconstructParams()
    if method not in METHODS:
        raise ReconstructionError(f"unknown reconstruction method {method!r}; expected one "
                                  f"of {list(METHODS)}", field="method", value=method)
    pre = params.preprocess
    if sigma_mm is not None:
        if not (math.isfinite(sigma_mm) and sigma_mm >= 0):
            raise ReconstructionError("sigma_mm must be >= 0", field="sigma_mm", value=sigma_mm)
        pre = PreprocessParams(**{**pre.__dict__, "sigma_mm": float(sigma_mm)})
    if context and method != "kriging":
        raise ReconstructionError("probes of other traces (context) are only used by the kriging "
                                  "method", field="context", value=len(context))
    path = as_trace_polyline(nominal)
    clean = preprocess(path, measured, pre)
    neighbours = [_context_trace(i, other, points, pre) for i, (other, points) in enumerate(context)]
    need = params.degree + 1
    if len(clean.s) < need:
        raise ReconstructionError(
            f"degree {params.degree} needs at least {need} distinct measured points, got "
            f"{len(clean.s)} after removing duplicates and outliers", field="points",
            value=len(clean.s))
    height: HeightModel
    try:
        if method == "deviation":
            curve, height = _deviation_model(path, clean, pre.sigma_mm, params)
        elif method == "kriging":
            curve, height = _kriging_model(path, clean, pre.sigma_mm, params, neighbours)
        else:
            if method == "interpolate" or pre.sigma_mm <= 0:
                curve = interpolate_curve(clean.points, params.degree)
            else:
                curve = smooth_curve(clean.points, pre.sigma_mm, params.degree)
            height = CurveHeight(curve, path)
    except GeometryError as exc:
        raise ReconstructionError(f"reconstruction failed: {exc.message}", field="points",
                                  value=exc.value) from exc
    samples = np.stack([clean.s, clean.dz], axis=1)
    reach = params.prior.wavelength_mm / 4.0 if method == "kriging" else 0.0
    span = (max(0.0, float(clean.s[0]) - reach), min(path.length_mm, float(clean.s[-1]) + reach))
    return Reconstruction(method=method, curve=curve, clean=clean, samples=samples,
                          max_mm=float(np.max(np.abs(clean.dz))),
                          rms_mm=float(np.sqrt(np.mean(clean.dz ** 2))),
                          nominal=path, _height_s=height, span_mm=span)


def _deviation_model(path: TracePolyline, clean: CleanPoints, sigma_mm: float,
                     params: ReconstructParams) -> tuple[NurbsCurve, SplineHeight]:
    spline = fit_deviation(clean.s, clean.dz, sigma_mm, params.degree)
    height = SplineHeight(path, spline, float(clean.s[0]), float(clean.s[-1]))
    return result_curve(path, height, params), height


def _context_trace(index: int, nominal: Any, measured: Any,
                   pre: PreprocessParams) -> tuple[TracePolyline, CleanPoints]:
    """Another trace's nominal and cleaned probes, errors named ``context[index]...``."""
    path = as_trace_polyline(nominal, field=f"context[{index}].nominal")
    return path, preprocess(path, measured, pre, field=f"context[{index}].points")


def _kriging_model(path: TracePolyline, clean: CleanPoints, sigma_mm: float,
                   params: ReconstructParams,
                   neighbours: Sequence[tuple[TracePolyline, CleanPoints]] = ()) -> tuple[NurbsCurve, KrigingHeight]:
    prior = DeviationPrior(**{**params.prior.__dict__, "sigma_mm": float(sigma_mm)})
    traces = [(path, clean), *neighbours]
    probes = Sites(np.concatenate([c.points[:, :2] for _, c in traces]),
                   np.concatenate([path_gradient(p, c.s) for p, c in traces]))
    center = joint_center([p for p, _ in traces]) if neighbours else path_center(path)
    posterior = fit_posterior(prior, probes, np.concatenate([c.dz for _, c in traces]),
                              center=center)
    height = KrigingHeight(path, posterior.prior, posterior.center, posterior.probes, posterior.alpha)
    return result_curve(path, height, params), height


def result_curve(path: TracePolyline, height: Callable[[np.ndarray], np.ndarray],
                  params: ReconstructParams) -> NurbsCurve:
    """Cubic interpolation of the real trace through the nominal's CL stations."""
    idx = chord_height_select(path.points, params.cl_tolerance_mm)
    s_cl = path.s[idx]
    if len(s_cl) < params.degree + 1:
        s_cl = np.linspace(0.0, path.length_mm, params.degree + 1)
    pts = path.at(s_cl)
    pts[:, 2] = height(s_cl)
    return interpolate_curve(pts, params.degree)
