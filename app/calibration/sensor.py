"""Height sensor calibration on the reference artifacts: time offset, offset, scale, slope bias.

Sensor model (mm; the carriage is the probe frame, :mod:`app.calibration.model`): the spot
lies at carriage + (o_x, o_y); a reading r is the height of the lit surface above the
sensor's zero, carriage z + o_z, times the scale k = 1 + scale error, plus a tilt bias
``b tan^2(theta)`` (theta: the surface's tilt; a triangulation spot on a slope is stretched
and its centroid moves, evenly in the tilt here), so the surface at the spot is

    h = z + o_z + r / k - b tan^2(theta).

Procedures (each a plan and a fit; the job drives the machine and the sensor):

* **time offset** tau (s): passes across one straight edge of the pad in both directions at
  speed v; a value stamped t was exposed at t - tau, so with the carriage positions the host
  computes from the stamps, the edge appears at X + v tau going +x and X - v tau going -x:
  ``tau = (mean(x_fwd) - mean(x_back)) / (2 v)`` (:func:`fit_time_offset`); an asymmetric
  spot or a lateral offset cancels between the two directions.
* **scale and z offset**: the carriage still above the pad's centre at heights spanning the
  range; ``r = k (pad_z - z - o_z)`` is a line in z: k from its slope, o_z from its intercept
  with the probe-measured pad height (:func:`fit_scale_and_z`); the pad is flat (no bias).
* **lateral offset and tilt bias**: a raster over the datum sphere's cap (its centre c and
  radius R known in the probe frame from the probe qualification); the corrected heights are
  fitted by ``c_z + dz + sqrt(R^2 - d^2) + b tan^2(theta)``, d the spot's distance from c's
  axis, over (o_x, o_y, dz, b) (:func:`fit_sphere_scan`); an even bias does not move the
  apparent centre, so o_x, o_y and b separate.  Their stated sd include the time offset's:
  the raster is paired with the fitted tau, and a tau off by its sd moves the lines
  (:func:`with_time_offset_sd`).

Pure: numpy/scipy.  Units: mm, s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import least_squares

from app.calibration.errors import CalibrationError


@dataclass(frozen=True)
class EdgePass:
    """One pass across an edge: carriage coordinate along the pass (n,) mm at each sample's
    stamp, the readings (n,) mm (NaN: no value), direction +1 / -1 and speed mm/s."""

    along_mm: np.ndarray
    values_mm: np.ndarray
    direction: int
    speed_mm_s: float


@dataclass(frozen=True)
class SensorCalibration:
    """What the calibration found: offset (3,) mm, scale k, time offset s, tilt bias b mm,
    and the sd of each from the fits' residuals."""

    offset_mm: tuple[float, float, float]
    scale: float
    time_offset_s: float
    slope_bias_mm: float = 0.0
    sd: dict[str, float] | None = None

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["offset_mm"] = list(self.offset_mm)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> SensorCalibration:
        offset = data.get("offset_mm")
        if not isinstance(offset, (list, tuple)) or len(offset) != 3:
            raise CalibrationError("offset_mm must be three numbers", field="offset_mm", value=offset)
        sd = data.get("sd")
        return cls((float(offset[0]), float(offset[1]), float(offset[2])), float(data["scale"]),  # type: ignore[arg-type]
                   float(data["time_offset_s"]), float(data.get("slope_bias_mm", 0.0)),  # type: ignore[arg-type]
                   {str(k): float(v) for k, v in sd.items()} if isinstance(sd, dict) else None)

    def surface_z(self, carriage: np.ndarray, readings: np.ndarray, tan2: np.ndarray | float = 0.0) -> np.ndarray:
        """Surface heights (n,) mm from readings (n,) with the carriage (n, 3) where they were
        exposed; ``tan2`` (n,): tan^2 of the surface tilt there (from the nominal)."""
        p = np.asarray(carriage, dtype=float)
        out: np.ndarray = p[:, 2] + self.offset_mm[2] + np.asarray(readings, dtype=float) / self.scale \
            - self.slope_bias_mm * np.asarray(tan2, dtype=float)
        return out

    def spot_xy(self, carriage: np.ndarray) -> np.ndarray:
        """Spot positions (n, 2) mm for carriage positions (n, 3)."""
        out: np.ndarray = np.asarray(carriage, dtype=float)[:, :2] + np.asarray(self.offset_mm[:2])
        return out


def edge_position(along_mm: np.ndarray, values_mm: np.ndarray, level_mm: float) -> float:
    """Where (mm along the pass) the readings first cross ``level_mm`` (linear interpolation
    between the two samples around it); NaN samples are skipped."""
    x = np.asarray(along_mm, dtype=float)
    v = np.asarray(values_mm, dtype=float)
    ok = np.isfinite(v)
    x, v = x[ok], v[ok]
    side = v > level_mm
    cross = np.flatnonzero(side[1:] != side[:-1])
    if not len(cross):
        raise CalibrationError("the pass never crosses the edge level", field="values_mm", value=level_mm)
    i = int(cross[0])
    f = (level_mm - v[i]) / (v[i + 1] - v[i])
    return float(x[i] + f * (x[i + 1] - x[i]))


def fit_time_offset(passes: Sequence[EdgePass], level_mm: float) -> tuple[float, float, float]:
    """(tau s, the edge's carriage position mm with tau removed, sd of tau s) from passes in
    both directions at one speed (see module docstring)."""
    fwd = [p for p in passes if p.direction > 0]
    back = [p for p in passes if p.direction < 0]
    if not fwd or not back:
        raise CalibrationError("the time offset needs passes in both directions", field="passes",
                               value=[len(fwd), len(back)])
    speeds = {round(p.speed_mm_s, 9) for p in passes}
    if len(speeds) != 1:
        raise CalibrationError("the passes must share one speed", field="passes", value=sorted(speeds))
    v = float(passes[0].speed_mm_s)
    xf = np.array([edge_position(p.along_mm, p.values_mm, level_mm) for p in fwd])
    xb = np.array([edge_position(p.along_mm, p.values_mm, level_mm) for p in back])
    tau = (xf.mean() - xb.mean()) / (2 * v)
    spread = [np.var(a, ddof=1) / len(a) for a in (xf, xb) if len(a) > 1]
    sd = math.sqrt(sum(spread)) / (2 * v) if len(spread) == 2 else math.nan
    return float(tau), float((xf.mean() + xb.mean()) / 2), sd


def fit_scale_and_z(heights_mm: np.ndarray, readings_mm: np.ndarray, pad_z_mm: float) -> tuple[float, float, float]:
    """(scale k, o_z mm, sd of o_z mm) from still readings over the pad at carriage heights
    (m,) mm: ``r = k (pad_z - z - o_z)``."""
    z = np.asarray(heights_mm, dtype=float)
    r = np.asarray(readings_mm, dtype=float)
    ok = np.isfinite(r)
    if ok.sum() < 3 or np.ptp(z[ok]) <= 0:
        raise CalibrationError("the scale needs valid readings at three or more heights", field="readings_mm",
                               value=int(ok.sum()))
    a = np.column_stack([np.ones(int(ok.sum())), z[ok]])
    coef, *_ = np.linalg.lstsq(a, r[ok], rcond=None)
    k = -float(coef[1])
    if not k > 0:
        raise CalibrationError("the readings do not fall as the carriage rises", field="readings_mm", value=k)
    oz = pad_z_mm - float(coef[0]) / k
    resid = r[ok] - a @ coef
    dof = max(int(ok.sum()) - 2, 1)
    cov = np.linalg.inv(a.T @ a) * float(resid @ resid) / dof
    # o_z = pad_z + coef0 / coef1: its variance by the delta method
    g = np.array([1.0 / coef[1], -coef[0] / coef[1] ** 2])
    return k, oz, float(math.sqrt(max(float(g @ cov @ g), 0.0)))


def fit_sphere_scan(carriage: np.ndarray, heights_mm: np.ndarray, centre_mm: Sequence[float], radius_mm: float,
                    offset_guess_mm: Sequence[float]) -> dict[str, float]:
    """Fit (o_x, o_y, dz, b) to heights (n,) mm corrected for o_z and k, measured with the
    carriage at (n, 3) mm where each was exposed, over a sphere of centre (3,) and radius R
    (module docstring).  Returns o_x, o_y, dz, b and their sd (``sd_o_x``...)."""
    p = np.asarray(carriage, dtype=float)
    h = np.asarray(heights_mm, dtype=float)
    ok = np.isfinite(h)
    if ok.sum() < 8:
        raise CalibrationError("the sphere scan has too few valid samples", field="heights_mm", value=int(ok.sum()))
    p, h = p[ok], h[ok]
    c = np.asarray(centre_mm, dtype=float)
    r2 = float(radius_mm) ** 2

    def model(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d2 = np.sum((p[:, :2] + q[:2] - c[:2]) ** 2, axis=1)
        inside = np.maximum(r2 - d2, 1e-9)
        return c[2] + q[2] + np.sqrt(inside) + q[3] * d2 / inside, d2

    def resid(q: np.ndarray) -> np.ndarray:
        out: np.ndarray = model(q)[0] - h
        return out

    start = np.array([offset_guess_mm[0], offset_guess_mm[1], 0.0, 0.0], dtype=float)
    fit = least_squares(resid, start, x_scale=np.array([0.01, 0.01, 0.001, 0.001]))
    res = fit.fun
    dof = max(len(res) - 4, 1)
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * float(res @ res) / dof
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        sd = np.full(4, math.nan)
    names = ("o_x", "o_y", "dz", "b")
    out = {n: float(v) for n, v in zip(names, fit.x)}
    out.update({f"sd_{n}": float(s) for n, s in zip(names, sd)})
    out["rms_mm"] = float(math.sqrt(float(res @ res) / len(res)))
    return out


TAU_STEP_S = 1e-3  # the time offset step of the sensitivity below


def with_time_offset_sd(fit: dict[str, float], carriage: np.ndarray, heights_mm: np.ndarray,
                        along: np.ndarray, speed_mm_s: float, sd_tau_s: float, centre_mm: Sequence[float],
                        radius_mm: float) -> dict[str, float]:
    """``fit`` (from :func:`fit_sphere_scan` on ``carriage`` (n, 3) mm and ``heights_mm``
    (n,)) with the time offset's uncertainty added to the sd of o_x, o_y and b.

    The raster was scanned with the fitted time offset tau applied: a tau off by d moves every
    sample along its line by ``speed_mm_s * d``, forward on lines scanned +x, backward on the
    others (``along`` (n,): +1 or -1 per sample).  The fit's own sd sees none of that, so the
    fit is repeated with the samples moved by one ``TAU_STEP_S``; the change per second times
    ``sd_tau_s`` is added in quadrature.  A serpentine of as many lines each way cancels it to
    first order; one more line one way leaves ~1/n of the shift in o_x."""
    out = dict(fit)
    if not math.isfinite(sd_tau_s) or sd_tau_s <= 0:
        return out
    moved = np.asarray(carriage, dtype=float).copy()
    moved[:, 0] += np.asarray(along, dtype=float) * speed_mm_s * TAU_STEP_S
    refit = fit_sphere_scan(moved, heights_mm, centre_mm, radius_mm, (fit["o_x"], fit["o_y"]))
    for name in ("o_x", "o_y", "b"):
        slope = (refit[name] - fit[name]) / TAU_STEP_S
        out[f"sd_{name}"] = float(math.hypot(fit[f"sd_{name}"], slope * sd_tau_s))
    return out
