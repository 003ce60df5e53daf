"""Probe point selection along a nominal trace: the seed's rule, a baseline, a better one.

Methods (``plan_probes(nominal, method, params)``):

``"adaptive"`` — the height-compensation paper's Fig. 3, exactly as published: the chord-height (sagitta) rule on
    the trace's CL points.  Dense where the 3-D trace bends, sparse where it is straight.
    Use it to reproduce the paper.  Caveat (measured, see the bench): it places points by
    the *nominal's* curvature, which is known from CAD anyway, and starves the flat
    stretches where the real part's deviation is just as large.
``"uniform"`` — the paper's baseline: N points evenly spaced by arc length (N given, or
    from eq. 1 via ``capability_k``/``confidence``).  Use it when nothing is known about
    the error.
``"deviation"`` — Conforma's planner for the job that matters: the real trace is the
    nominal (exact, from CAD) plus a smooth deviation (machining error + placement), so
    the probes only have to capture the deviation dz(s), and the reconstruction adds it
    back to the nominal (``reconstruct(..., method="deviation")``).  The count comes from
    the cubic-spline error bound for a deviation of amplitude A and shortest wavelength
    lambda, ``h = (384/5 * e_budget / (A (2 pi / lambda)^4))^(1/4)`` with the noise's share
    taken off the target error; stations are even in arc length with slightly shorter end
    intervals (where a spline's error is largest).  Use it whenever the CAD nominal is
    known (always, in this product); state A/lambda for the process, or give ``count``.
``"kriging"`` — Conforma's best per-trace planner (pair it with
    ``reconstruct(..., method="kriging")``): the deviation is a Gaussian process, a
    band-limited machining error (amplitude A, shortest wavelength lambda) plus the part's
    rigid placement error, whose height effect is known to first order from the CAD
    slopes (:mod:`app.probing.deviation_prior`).  Stations minimise the largest posterior
    sd along the trace; the count is the fewest probes with ``coverage`` x that sd <= the
    target (:mod:`app.probing.minimax`).  Use it whenever the nominal has normals (the
    draped traces do) and the process's A/lambda/placement tolerances are roughly known;
    it needs ~10-25 % fewer probes than "deviation" on S1, and states its predicted error
    (``ProbePlan.predicted_sd_mm``).  A sequential (decide after each touch) version
    would pick the same stations: with the prior fixed, the posterior sd does not depend
    on the values read.

Which one: reproduce the paper -> "adaptive"; nothing known about the part ->
"uniform"; CAD nominal known, few probes wanted -> "kriging" (or "deviation" when the
nominal has no normals and a plain spline model is preferred); several traces of one part
probed in one session -> :func:`app.probing.joint.plan_joint` (kriging over all of them
together: the fewest probes of all, see tests/bench/test_bench_probing.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from annotated_types import Ge, Gt, Le, Lt

from app.domain.checks import require_non_negative, require_positive
from app.domain.errors import InvalidInput
from app.geometry.traces import TracePolyline, as_trace_polyline
from app.probing.deviation_prior import DeviationPrior
from app.probing.minimax import auto_count, design_grid, design_stations
from app.probing.point_count import PointCount, seed_point_count

Method = Literal["adaptive", "uniform", "deviation", "kriging"]
METHODS: tuple[str, ...] = ("adaptive", "uniform", "deviation", "kriging")


class PlanError(InvalidInput):
    """Probe-planning parameters that cannot be used."""


@dataclass(frozen=True)
class PlanParams:
    """Parameters of every planner (mm unless named otherwise).

    chord_error_mm: allowed chord height e of the seed's adaptive rule.
    cl_tolerance_mm: chordal tolerance of the CL points the adaptive rule starts from.
    count: number of probes for "uniform"/"deviation" (overrides the derived counts).
    capability_k, confidence: eq. 1 inputs giving the count for "uniform" (both or none).
    deviation_amplitude_mm, deviation_wavelength_mm: expected amplitude and shortest
        wavelength of the real part's deviation from CAD ("deviation" planner).
    target_error_mm: max height error wanted from the reconstruction ("deviation").
    probe_sigma_mm: probe repeatability (1 sigma).
    end_ratio: end-interval length / interior spacing for "deviation" (0 < r <= 1).
    min_count: fewest probes any planner returns (cubic reconstruction needs 4).
    placement_xy_mm, placement_z_mm, placement_rz_deg, tilt_rad: 1-sigma rigid placement
        errors of the part ("kriging"); peak_factor: peak / rms of the machining error;
        coverage: the "kriging" count makes coverage x largest posterior sd <= target.
    exchange: "field" automatic count: refine the minimal design by exchange moves
        (:mod:`app.probing.field_exchange`): 2-11 % fewer stations on the bench's boards, about
        twice the planning time, and less slack when a touch is rejected as an outlier.
    The bounds in the annotations are the ranges a job may ask for (a kind's parameter model
    reads them); ``__post_init__`` checks what the planners need.
    """

    chord_error_mm: Annotated[float, Gt(0), Le(10)] = 0.005
    cl_tolerance_mm: Annotated[float, Gt(0), Le(1)] = 0.001
    count: Annotated[int, Ge(4), Le(10_000)] | None = None
    capability_k: Annotated[float, Gt(0), Lt(1)] | None = None
    confidence: Annotated[float, Gt(0.5), Lt(1)] | None = None
    deviation_amplitude_mm: Annotated[float, Gt(0), Le(10)] = 0.2
    deviation_wavelength_mm: Annotated[float, Gt(0), Le(10_000)] = 20.0
    target_error_mm: Annotated[float, Gt(0), Le(10)] = 0.005
    probe_sigma_mm: Annotated[float, Ge(0), Le(1)] = 0.001
    end_ratio: float = 0.7
    min_count: int = 4
    placement_xy_mm: float = 0.1
    placement_z_mm: float = 0.05
    placement_rz_deg: float = 0.2
    tilt_rad: float = 0.001
    peak_factor: float = 3.0
    coverage: Annotated[float, Gt(0), Le(10)] = 3.0
    exchange: bool = False

    def __post_init__(self) -> None:
        require_positive(self, ("chord_error_mm", "cl_tolerance_mm", "deviation_amplitude_mm",
                                "deviation_wavelength_mm", "target_error_mm"), PlanError)
        require_non_negative(self, ("probe_sigma_mm",), PlanError)
        if not (0 < self.end_ratio <= 1):
            raise PlanError("end_ratio must be in (0, 1]", field="end_ratio", value=self.end_ratio)
        if self.count is not None and (isinstance(self.count, bool) or int(self.count) != self.count
                                       or self.count < 2):
            raise PlanError("count must be an integer >= 2", field="count", value=self.count)
        require_positive(self, ("coverage",), PlanError)
        self.prior()  # validates the prior's fields under their own names
        if (self.capability_k is None) != (self.confidence is None):
            raise PlanError("capability_k and confidence go together", field="capability_k",
                            value=self.capability_k)

    def prior(self) -> DeviationPrior:
        """The "kriging" planner's deviation prior built from these parameters."""
        return DeviationPrior(
            amplitude_mm=self.deviation_amplitude_mm, wavelength_mm=self.deviation_wavelength_mm,
            peak_factor=self.peak_factor, placement_xy_mm=self.placement_xy_mm,
            placement_z_mm=self.placement_z_mm, placement_rz_deg=self.placement_rz_deg,
            tilt_rad=self.tilt_rad, sigma_mm=self.probe_sigma_mm)


@dataclass(frozen=True, eq=False)
class ProbePlan:
    """Where to probe.

    method: planner name.  s_mm: (m,) arc length of each probe along the nominal.
    points: (m, 3) nominal probe points, mm.  normals: (m, 3) or None.
    cl_points: (n, 3) CL points the adaptive rule worked on (None for other methods).
    point_count: eq. 1 result when the count came from it.  spacing_mm: design spacing
        of the deviation planner (None otherwise).  predicted_sd_mm: largest posterior sd
        of the reconstructed height along the trace ("kriging" only), mm.
    """

    method: str
    s_mm: np.ndarray
    points: np.ndarray
    normals: np.ndarray | None
    cl_points: np.ndarray | None = None
    point_count: PointCount | None = None
    spacing_mm: float | None = None
    predicted_sd_mm: float | None = None

    @property
    def count(self) -> int:
        return int(len(self.s_mm))


def chord_heights(points: np.ndarray, start: int, stop: int) -> float:
    """Largest distance (mm) of points[start+1:stop] to the segment points[start]-points[stop]."""
    a, b = points[start], points[stop]
    mid = points[start + 1:stop]
    if len(mid) == 0:
        return 0.0
    d = b - a
    dd = float(d @ d)
    t = np.clip((mid - a) @ d / dd, 0.0, 1.0) if dd > 0 else np.zeros(len(mid))
    return float(np.max(np.linalg.norm(a + t[:, None] * d - mid, axis=1)))


def chord_height_select(cl_points: np.ndarray, chord_error_mm: float) -> np.ndarray:
    """The published chord-height rule (Fig. 3): indices (m,) of the measurement points among CL points (n, d).

    C1 is the first measurement point; with start i and j = i + 2, the chord height e_ij
    (largest distance of C(i+1)..C(j-1) from segment Ci-Cj) is compared with e; while
    e_ij <= e, j advances; when e_ij > e, C(j-1) becomes a measurement point and the new
    start.  The last CL point is always a measurement point.  Guarantee: every CL point
    lies within e of the chord of the two measurement points around it.
    """
    pts = np.asarray(cl_points, dtype=float)
    n = len(pts)
    if n < 2:
        raise PlanError("need at least 2 CL points", field="cl_points", value=n)
    chosen = [0]
    i, j = 0, 2
    while j < n:
        if chord_heights(pts, i, j) <= chord_error_mm:
            j += 1
        else:
            i = j - 1
            chosen.append(i)
            j = i + 2
    if chosen[-1] != n - 1:
        chosen.append(n - 1)
    return np.asarray(chosen, dtype=int)


def uniform_stations(length_mm: float, count: int) -> np.ndarray:
    """``count`` arc lengths (mm) evenly spaced over [0, length], both ends included."""
    return np.linspace(0.0, length_mm, int(count))


def deviation_spacing(params: PlanParams) -> float:
    """Design spacing h (mm) from the cubic-spline bound 5/384 h^4 max|dz''''| <= budget.

    max|dz''''| is taken as A (2 pi / lambda)^4; the budget is the target error minus
    2 sigma for the probe noise (a spline through noisy samples keeps ~1-2 sigma).
    """
    budget = params.target_error_mm - 2.0 * params.probe_sigma_mm
    if budget <= 0:
        raise PlanError("target_error_mm must exceed 2 * probe_sigma_mm",
                        field="target_error_mm", value=params.target_error_mm)
    d4 = params.deviation_amplitude_mm * (2 * math.pi / params.deviation_wavelength_mm) ** 4
    out: float = (384.0 / 5.0 * budget / d4) ** 0.25
    return out


def deviation_stations(length_mm: float, count: int, end_ratio: float) -> np.ndarray:
    """``count`` arc lengths: even interior spacing, the two end intervals ``end_ratio`` x."""
    count = int(count)
    if count <= 3:
        return np.linspace(0.0, length_mm, count)
    h = length_mm / (count - 3 + 2 * end_ratio)
    interior = end_ratio * h + h * np.arange(count - 2)
    return np.concatenate([[0.0], interior, [length_mm]])


def _cl_points(path: TracePolyline, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """CL points (n, 3) and their s (n,) from the dense nominal at chordal tolerance tol."""
    idx = chord_height_select(path.points, tol)
    return path.points[idx], path.s[idx]


def plan_probes(nominal: Any, method: str = "adaptive",
                params: PlanParams | None = None) -> ProbePlan:
    """Plan probe points on a nominal trace (see the module doc for which method when).

    nominal: TracePolyline, anything with ``.points`` (k, 3)[, ``.normals``] or (k, 3).
    Returns a :class:`ProbePlan` ordered by arc length.
    """
    params = params or PlanParams()
    path = as_trace_polyline(nominal)
    if method not in METHODS:
        raise PlanError(f"unknown probe planning method {method!r}; expected one of "
                        f"{list(METHODS)}", field="method", value=method)
    L = path.length_mm
    if method == "adaptive":
        cl, cl_s = _cl_points(path, params.cl_tolerance_mm)
        idx = chord_height_select(cl, params.chord_error_mm)
        s = cl_s[idx]
        return ProbePlan("adaptive", s, cl[idx], path.normals_at(s), cl_points=cl)
    if method == "kriging":
        return _kriging_plan(path, params)
    point_count = None
    spacing = None
    if params.count is not None:
        count = int(params.count)
    elif method == "uniform":
        if params.capability_k is None or params.confidence is None:
            raise PlanError("uniform planning needs count or capability_k + confidence",
                            field="count", value=None)
        point_count = seed_point_count(params.capability_k, params.confidence)
        count = point_count.count
    else:
        spacing = deviation_spacing(params)
        count = max(params.min_count, int(math.ceil(L / spacing)) + 1)
    if method == "uniform":
        s = uniform_stations(L, count)
    else:
        s = deviation_stations(L, count, params.end_ratio)
    return ProbePlan(method, s, path.at(s), path.normals_at(s), point_count=point_count,
                     spacing_mm=spacing)


def _kriging_plan(path: TracePolyline, params: PlanParams) -> ProbePlan:
    grid = design_grid(path, params.prior())
    if params.count is not None:
        count = int(params.count)
    else:
        count = auto_count(grid, params.target_error_mm, params.coverage, params.min_count)
    design = design_stations(grid, count)
    s = design.s_mm
    sd = None if math.isnan(design.max_sd_mm) else design.max_sd_mm
    return ProbePlan("kriging", s, path.at(s), path.normals_at(s), predicted_sd_mm=sd)
