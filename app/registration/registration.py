"""Part registration: where the part really sits (dx, dy, dz, rz) from datum touches.

Beyond the seed (which only corrects height).  Model: a rigid placement of the part
(:class:`app.geometry.placement.Placement`), a rotation ``rz`` about the vertical axis
through ``pivot`` then a translation,

    machine = R(rz) (part - pivot) + pivot + (dx, dy, dz).

Datum touches: measured machine points m_i, each with the nominal (part-frame) point
q_i and outward unit normal n_i of the face it touched.  Residual (point-to-plane):

    r_i = n_i . (T^-1(m_i) - q_i)

solved by Gauss-Newton (analytic Jacobian); when a ``surface`` callable is given the foot
point and normal are re-found after every step (curved faces), otherwise the touched faces
are taken as planes.  A touch made along direction d has noise along d, i.e. sigma |n.d|
along the normal; rows are weighted accordingly.  Covariance sigma^2 (J^T W J)^-1 gives
the standard uncertainties; sigma^2 = max(probe sigma^2, residual variance).

Observability (say which touches determine what):
* dz needs a face with a vertical normal component (the top); dx a normal with an x
  component; dy a y component; rz two touches on faces with horizontal normals at
  different lever arms, or top touches on slopes.
* Side touches (x-face and y-face, probing horizontally, G38.2 X/Y) determine dx, dy, rz
  directly; they need a probe that triggers sideways (the seed's touch probe does).
* The mock firmware probes along -Z only.  With -Z touches alone: touches on a flat top
  give dz only (dx, dy, rz unobservable -> DegenerateDatumError unless
  ``estimate=("dz",)``); on a sloped/free-form top or chamfers the slopes make dx, dy, rz
  observable, with an uncertainty ~ sigma / slope; BUT the machining error of a
  free-form top (not of the planar side faces) then biases them by ~ error / slope
  (0.15 mm over slopes ~0.3 -> ~0.5 mm): use planar features.  ``plan_datum_probes``
  with ``mode="z_only"`` therefore prefers sloped faces and reports the predicted
  uncertainties; side faces can also be located with -Z touches by edge finding
  (:func:`app.registration.datum_plan.find_edge`): the way to register on the mock.
Lengths mm, angles rad inside (``rz_deg`` at the boundary).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.domain.checks import require_positive
from app.domain.errors import InvalidInput
from app.geometry.placement import Placement, remove_placement
from app.geometry.traces import TracePolyline, as_trace_polyline

__all__ = [
    "PARAMETERS",
    "DegenerateDatumError",
    "Registration",
    "RegistrationError",
    "RegistrationParams",
    "fit_placement",
    "information_rows",
    "place_path",
]

PARAMETERS: tuple[str, ...] = ("dx", "dy", "dz", "rz")
SurfaceFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


class RegistrationError(InvalidInput):
    """Datum touches or settings that cannot give a placement (422)."""


class DegenerateDatumError(RegistrationError):
    """The touches do not determine some placement parameter (e.g. all on one face)."""


def _as_points(points: Any, field: str) -> np.ndarray:
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise RegistrationError(f"{field} must be numeric", field=field,
                                value=str(points)[:60]) from exc
    if p.ndim != 2 or p.shape[1] not in (2, 3) or not np.isfinite(p).all():
        raise RegistrationError(f"{field} must be a finite (n, 2) or (n, 3) array",
                                field=field, value=list(p.shape))
    return p


def place_path(nominal: Any, placement: Placement) -> TracePolyline:
    """A nominal trace (TracePolyline / ``.points`` (k, 3) / array) moved into the machine
    frame: points placed, normals rotated, arc lengths and slope stretch unchanged (rigid
    motion); the slope summary (part-frame coordinates) is not carried."""
    path = as_trace_polyline(nominal)
    normals = None if path.normals is None else placement.rotate(path.normals)
    return TracePolyline(points=placement.apply(path.points), s=path.s.copy(), normals=normals,
                         slope_stretch=path.slope_stretch)


@dataclass(frozen=True)
class RegistrationParams:
    """Fit settings.  sigma_mm: probe repeatability along its direction.  estimate: the
    parameters to estimate (others held at 0).  pivot_xy: rotation axis (mm).
    max_iterations / step_tol_mm: Gauss-Newton stop.  min_relative_sv: smallest singular
    value of the scaled Jacobian, relative to the largest, that counts as observable."""

    sigma_mm: float = 0.001
    estimate: tuple[str, ...] = PARAMETERS
    pivot_xy: tuple[float, float] = (0.0, 0.0)
    max_iterations: int = 30
    step_tol_mm: float = 1e-9
    min_relative_sv: float = 1e-4

    def __post_init__(self) -> None:
        require_positive(self, ("sigma_mm",), RegistrationError)
        bad = [e for e in self.estimate if e not in PARAMETERS]
        if bad or not self.estimate or len(set(self.estimate)) != len(self.estimate):
            raise RegistrationError(f"estimate must be distinct names from {list(PARAMETERS)}",
                                    field="estimate", value=list(self.estimate))


@dataclass(frozen=True, eq=False)
class Registration:
    """Fit result.  placement: estimate.  std: standard uncertainty per estimated
    parameter (mm; rz in rad).  covariance: (p, p) in ``estimated`` order.  residuals_mm:
    (n,) point-to-plane residuals at the solution.  rms_mm.  iterations.
    singular_values: (p,) of the scaled, weighted Jacobian.  sigma_used_mm."""

    placement: Placement
    estimated: tuple[str, ...]
    std: dict[str, float]
    covariance: np.ndarray
    residuals_mm: np.ndarray
    rms_mm: float
    iterations: int
    singular_values: np.ndarray
    sigma_used_mm: float

    def to_result(self) -> dict[str, Any]:
        unc = {f"{k}_mm": v for k, v in self.std.items() if k != "rz"}
        if "rz" in self.std:
            unc["rz_deg"] = math.degrees(self.std["rz"])
        return {"placement": self.placement.to_dict(), "uncertainty": unc,
                "estimated": list(self.estimated), "rms_mm": self.rms_mm,
                "touches": len(self.residuals_mm), "iterations": self.iterations}


def information_rows(points: np.ndarray, normals: np.ndarray, pivot_xy: tuple[float, float],
                     lever_mm: float) -> np.ndarray:
    """(n, 4) sensitivity of the normal distance to (dx, dy, dz, rz * lever_mm)."""
    arm = points[:, :2] - np.asarray(pivot_xy, dtype=float)
    moment = arm[:, 0] * normals[:, 1] - arm[:, 1] * normals[:, 0]
    return np.column_stack([normals, moment / lever_mm])


def _unobservable(vector: np.ndarray, names: tuple[str, ...]) -> list[str]:
    v = np.abs(vector) / np.abs(vector).max()
    return [n for n, x in zip(names, v) if x > 0.3]


def fit_placement(nominal_points: Any, normals: Any, measured: Any,
                  params: RegistrationParams | None = None, surface: SurfaceFn | None = None,
                  directions: Any = None) -> Registration:
    """Estimate the placement from datum touches (see the module doc).

    nominal_points: (n, 3) touched face points, part frame, mm.  normals: (n, 3) outward
    face normals, part frame.  measured: (n, 3) trigger points, machine frame.
    surface: optional callable part points (n, 3) -> (foot points (n, 3), unit normals
    (n, 3)) for curved faces.  directions: (n, 3) probe travel directions (default -n).
    Raises DegenerateDatumError naming the parameters the touches cannot determine.
    """
    params = params or RegistrationParams()
    q = _as_points(nominal_points, "nominal_points")
    n = _as_points(normals, "normals")
    m = _as_points(measured, "measured")
    if not (q.shape == n.shape == m.shape and q.shape[1] == 3):
        raise RegistrationError("nominal_points, normals and measured must all be (n, 3)",
                                field="measured", value=[list(q.shape), list(n.shape),
                                                         list(m.shape)])
    length = np.linalg.norm(n, axis=1)
    if np.any(length < 1e-9):
        raise RegistrationError("a datum normal is zero", field="normals",
                                value=int(np.argmin(length)))
    n = n / length[:, None]
    d = -n if directions is None else _as_points(directions, "directions")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    cols = [PARAMETERS.index(e) for e in params.estimate]
    names = tuple(PARAMETERS[c] for c in cols)
    if len(q) < len(cols):
        raise DegenerateDatumError(f"{len(q)} touches cannot determine {len(cols)} parameters "
                                   f"{list(names)}", field="measured", value=len(q))
    pivot = np.array([params.pivot_xy[0], params.pivot_xy[1], 0.0])
    lever = max(float(np.sqrt(np.mean(np.sum((q[:, :2] - pivot[:2]) ** 2, axis=1)))), 1.0)
    theta = np.zeros(4)
    foot, nrm = q, n
    for iteration in range(1, params.max_iterations + 1):
        pl = Placement(float(theta[0]), float(theta[1]), float(theta[2]), float(theta[3]), float(pivot[0]),
                       float(pivot[1]))
        p_part = remove_placement(m, pl)
        if surface is not None:
            foot, nrm = (np.asarray(a, dtype=float) for a in surface(p_part))
        r = np.einsum("ij,ij->i", nrm, p_part - foot)
        rot = pl.rotation()
        c, s = math.cos(theta[3]), math.sin(theta[3])
        d_rt = np.array([[-s, c, 0.0], [-c, -s, 0.0], [0.0, 0.0, 0.0]])
        rel = m - pivot - theta[:3]
        jac = np.column_stack([-(nrm @ rot.T), np.einsum("ij,ij->i", nrm, rel @ d_rt.T)])
        # noise sigma |n.d| along the normal (d in the machine frame, n rotated into it)
        weight = 1.0 / np.maximum(np.abs(np.einsum("ij,ij->i", nrm @ rot.T, d)), 1e-3)
        jw = jac[:, cols] * weight[:, None]
        step, *_ = np.linalg.lstsq(jw, -r * weight, rcond=None)
        theta[cols] += step
        scale = np.where(np.array(cols) == 3, lever, 1.0)
        if np.max(np.abs(step * scale)) < params.step_tol_mm:
            break
    scale = np.where(np.array(cols) == 3, lever, 1.0)
    sv = np.linalg.svd(jw / scale, compute_uv=False)
    _, _, vt = np.linalg.svd(jw / scale)
    if sv[-1] < params.min_relative_sv * sv[0]:
        weak = _unobservable(vt[-1], names)
        raise DegenerateDatumError(
            f"the datum touches do not determine {weak} (their normals/lever arms leave that "
            f"motion unseen; e.g. all touches on one face): add touches on faces that see it "
            f"or estimate fewer parameters", field="measured", value=weak)
    pl = Placement(float(theta[0]), float(theta[1]), float(theta[2]), float(theta[3]), float(pivot[0]), float(pivot[1]))
    p_part = remove_placement(m, pl)
    if surface is not None:
        foot, nrm = (np.asarray(a, dtype=float) for a in surface(p_part))
    r = np.einsum("ij,ij->i", nrm, p_part - foot)
    dof = len(r) - len(cols)
    rw = r * weight
    sigma2 = params.sigma_mm ** 2
    if dof > 0:
        sigma2 = max(sigma2, float(rw @ rw) / dof)
    cov = sigma2 * np.linalg.inv(jw.T @ jw)
    std = {name: float(math.sqrt(cov[i, i])) for i, name in enumerate(names)}
    return Registration(placement=pl, estimated=names, std=std, covariance=cov, residuals_mm=r,
                        rms_mm=float(np.sqrt(np.mean(r ** 2))), iterations=iteration,
                        singular_values=sv, sigma_used_mm=math.sqrt(sigma2))
