"""The real surface height along a trace, as data (so a reconstruction can be stored and
read back exactly, instead of being rebuilt from its probes).

Each model is ``height(s (m,)) -> (m,)`` mm at nominal arc lengths ``s`` over a
:class:`~app.geometry.traces.TracePolyline`, and :meth:`arrays` gives the numbers it is made
of; :func:`height_model` builds it again from them, bit for bit the same function:

* :class:`CurveHeight` (``interpolate``, ``approximate``): the curve's z where its top view
  passes closest to the nominal point (the numbers are the curve's);
* :class:`SplineHeight` (``deviation``): nominal z + a spline dz(s), held at its end values
  outside the probed span;
* :class:`KrigingHeight` (``kriging``): nominal z + the posterior mean of the deviation,
  K(sites, probes) alpha;
* :class:`FieldHeight` (``field``): nominal z + the machining and placement splines of the
  run's fitted field.

Pure: numpy/scipy.  Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.interpolate import BSpline

from app.geometry.nurbs import NurbsCurve
from app.geometry.traces import TracePolyline
from app.probing.deviation_prior import DeviationPrior, Sites, path_sites, prior_covariance
from app.reconstruction.preprocess import ReconstructionError


class HeightModel(Protocol):
    @property
    def kind(self) -> str: ...

    def __call__(self, s: np.ndarray) -> np.ndarray: ...

    def arrays(self) -> dict[str, np.ndarray]: ...


@dataclass(frozen=True, eq=False)
class CurveHeight:
    curve: NurbsCurve
    path: TracePolyline
    kind: str = "curve"
    _top: NurbsCurve = field(init=False, repr=False)

    def __post_init__(self) -> None:
        c = self.curve
        object.__setattr__(self, "_top", NurbsCurve(c.degree, c.knots, c.control_points[:, :2], c.weights))

    def __call__(self, s: np.ndarray) -> np.ndarray:
        inv = self._top.invert(self.path.at(s)[:, :2])
        return self.curve.evaluate(inv.u)[:, 2]

    def arrays(self) -> dict[str, np.ndarray]:
        return {}  # the reconstruction's own curve


def _spline_arrays(name: str, spline: BSpline) -> dict[str, np.ndarray]:
    return {f"{name}_t": np.asarray(spline.t), f"{name}_c": np.asarray(spline.c),
            f"{name}_k": np.asarray(int(spline.k)), f"{name}_extrapolate": np.asarray(bool(spline.extrapolate))}


def _spline(name: str, arrays: dict[str, np.ndarray]) -> BSpline:
    return BSpline(arrays[f"{name}_t"], arrays[f"{name}_c"], int(arrays[f"{name}_k"]),
                   extrapolate=bool(arrays[f"{name}_extrapolate"]))


@dataclass(frozen=True, eq=False)
class SplineHeight:
    path: TracePolyline
    spline: BSpline
    lo: float
    hi: float
    kind: str = "spline"

    def __call__(self, s: np.ndarray) -> np.ndarray:
        # outside the probed span the deviation is held at its end value (no extrapolation)
        out: np.ndarray = self.path.z_at(s) + self.spline(np.clip(s, self.lo, self.hi))
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        return {**_spline_arrays("dz", self.spline), "span": np.array([self.lo, self.hi])}


@dataclass(frozen=True, eq=False)
class KrigingHeight:
    path: TracePolyline
    prior: DeviationPrior
    center: np.ndarray
    probes: Sites
    alpha: np.ndarray
    kind: str = "kriging"

    def __call__(self, s: np.ndarray) -> np.ndarray:
        # the posterior mean (DeviationPosterior.mean) at the trace's sites
        out: np.ndarray = self.path.z_at(s) + prior_covariance(self.prior, path_sites(self.path, s), self.probes,
                                                               self.center) @ self.alpha
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        return {"prior": np.array([getattr(self.prior, k) for k in _PRIOR_FIELDS]),
                "center": np.asarray(self.center), "probes_xy": self.probes.xy, "probes_grad": self.probes.grad,
                "alpha": np.asarray(self.alpha)}


_PRIOR_FIELDS = ("amplitude_mm", "wavelength_mm", "peak_factor", "placement_xy_mm", "placement_z_mm",
                 "placement_rz_deg", "tilt_rad", "sigma_mm")


@dataclass(frozen=True, eq=False)
class FieldHeight:
    path: TracePolyline
    machining: BSpline
    placement: BSpline
    kind: str = "field"

    def __call__(self, s: np.ndarray) -> np.ndarray:
        out: np.ndarray = self.path.z_at(s) + self.machining(s) + self.placement(s)
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        return {**_spline_arrays("machining", self.machining), **_spline_arrays("placement", self.placement)}


def height_model(kind: str, path: TracePolyline, arrays: dict[str, np.ndarray], curve: NurbsCurve) -> HeightModel:
    """The model ``kind`` over ``path`` from its :meth:`arrays` (``curve``: the reconstruction's)."""
    try:
        if kind == "curve":
            return CurveHeight(curve, path)
        if kind == "spline":
            lo, hi = (float(v) for v in arrays["span"])
            return SplineHeight(path, _spline("dz", arrays), lo, hi)
        if kind == "kriging":
            prior = DeviationPrior(**{k: float(v) for k, v in zip(_PRIOR_FIELDS, arrays["prior"])})
            return KrigingHeight(path, prior, arrays["center"], Sites(arrays["probes_xy"], arrays["probes_grad"]),
                                 arrays["alpha"])
        if kind == "field":
            return FieldHeight(path, _spline("machining", arrays), _spline("placement", arrays))
    except (KeyError, ValueError, TypeError) as exc:
        raise ReconstructionError(f"stored {kind} height model is incomplete ({exc})", field="reconstruction",
                                  value=kind) from None
    raise ReconstructionError(f"unknown stored height model {kind!r}", field="reconstruction", value=kind)
