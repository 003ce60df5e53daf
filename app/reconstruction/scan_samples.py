"""Scan samples to deviations: where each sample was, what the surface was there, and by
how much it differs from the nominal.

For one pass (carriage waypoints (m, 3), speed, the stored readings (n,)): the carriage at
each sample's exposure (:func:`app.probing.scan_path.sample_positions`, the calibrated time
offset; or, when the controller sampled its axes with the sensor,
:func:`exposure_positions` from those positions), the spot there (+ the calibrated lateral offset), the surface height
from the calibrated offset, scale and tilt bias (the tilt from the nominal slope), minus the nominal
height at the spot: the deviation.  Dropouts (NaN readings) are dropped.
:func:`block_average` then averages each run of ``k`` consecutive valid samples of a pass
(their mean position and deviation; noise down by sqrt(k)) so a fit sees fewer, better points.

Pure: numpy.  Units: mm, s.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from app.calibration.sensor import SensorCalibration
from app.probing.scan_path import sample_positions


def pass_deviations(waypoints: np.ndarray, speed_mm_s: float, values: np.ndarray, rate_hz: float,
                    calibration: SensorCalibration, height: Callable[[np.ndarray], np.ndarray],
                    slope: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Spot xy (k, 2) mm and deviation (k,) mm of the pass's valid samples (k <= n)."""
    v = np.asarray(values, dtype=float)
    carriage = sample_positions(waypoints, speed_mm_s, len(v), rate_hz, calibration.time_offset_s)
    return carriage_deviations(carriage, v, calibration, height, slope)


def exposure_positions(stamps_s: np.ndarray, sampled: np.ndarray, time_offset_s: float) -> np.ndarray:
    """The carriage (n, 3) mm where each sample was exposed, from positions sampled with the
    readings (a controller sampling its axes and the sensor together): ``sampled`` (n, 3)
    at ``stamps_s`` (n,) s, interpolated at ``stamps - time_offset_s`` (held at the ends)."""
    t = np.asarray(stamps_s, dtype=float)
    p = np.asarray(sampled, dtype=float).reshape(-1, 3)
    out = np.empty_like(p)
    for axis in range(3):
        out[:, axis] = np.interp(t - time_offset_s, t, p[:, axis]) if len(t) else p[:, axis]
    return out


def carriage_deviations(carriage: np.ndarray, values: np.ndarray, calibration: SensorCalibration,
                        height: Callable[[np.ndarray], np.ndarray],
                        slope: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Spot xy (k, 2) mm and deviation (k,) mm of the valid samples (k <= n), the carriage
    (n, 3) mm where each of the readings (n,) mm was exposed."""
    v = np.asarray(values, dtype=float)
    xy = calibration.spot_xy(carriage)
    ok = np.isfinite(v)
    g = slope(xy[ok]) if ok.any() else np.zeros((0, 2))
    tan2 = np.sum(np.asarray(g, dtype=float) ** 2, axis=1)
    z = calibration.surface_z(carriage[ok], v[ok], tan2)
    nominal = height(xy[ok])
    good = np.isfinite(nominal)
    return xy[ok][good], (z - nominal)[good]


def block_average(xy: np.ndarray, dz: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of consecutive runs of ``k`` samples: xy (ceil(n/k), 2), dz (ceil(n/k),)."""
    n = len(dz)
    if k <= 1 or n == 0:
        return np.asarray(xy, dtype=float), np.asarray(dz, dtype=float)
    group = np.arange(n) // k
    counts = np.bincount(group)
    mx = np.bincount(group, weights=xy[:, 0]) / counts
    my = np.bincount(group, weights=xy[:, 1]) / counts
    mz = np.bincount(group, weights=dz) / counts
    return np.column_stack([mx, my]), mz
