"""The point laser sensor's optics formula, shared by every simulated sensor.

One formula for the mock LK-G controller (:mod:`hardware.height_sensor.optics`, the mock
machine's world) and the LinuxCNC simulator's HAL component
(:mod:`hardware.linuxcnc.sensor_hal`, the simulated block under the head).  This module
imports only ``math`` and numpy: the HAL component loads it by file path under the
system Python (which has LinuxCNC's ``hal`` module and numpy, not Conforma's packages).

* :func:`spot_points`: where the spot's light falls: its centre and six points on a circle
  of a third of the spot diameter (n, 7, 2);
* :func:`optical_values`: the value from the heights averaged over those points, the tilt
  at the centre and the sensor's zero: ``(h - z0 + bias) * (1 + scale_error) + noise``,
  quantised, with ``bias = slope_bias_mm * tan(theta)^2``; NaN (no value) beyond the
  acceptance angle, where ``lost`` says so (dark or specular spots) and at random with
  ``dropout_rate``.  Over-range values are kept (the output stage marks them).

Units: mm, degrees.
"""

from __future__ import annotations

import math

import numpy as np

SPOT_PATTERN = np.array([[0.0, 0.0]] + [[math.cos(a), math.sin(a)] for a in np.arange(6) * math.pi / 3]) / 3.0


def spot_points(spot_xy: np.ndarray, spot_mm: float) -> np.ndarray:
    """The lit points (n, k, 2) mm around spot centres (n, 2): k = 7, or 1 for a zero spot."""
    pattern = SPOT_PATTERN[:1] if spot_mm == 0 else SPOT_PATTERN * spot_mm
    xy = np.asarray(spot_xy, dtype=float).reshape(-1, 2)
    out: np.ndarray = xy[:, None, :] + pattern[None, :, :]
    return out


def optical_values(heights: np.ndarray, cos_tilt: np.ndarray, zero_z: np.ndarray, rng: np.random.Generator, *,
                   noise_mm: float, resolution_mm: float, scale_error: float, slope_bias_mm: float,
                   acceptance_deg: float, dropout_rate: float, lost: np.ndarray | None = None) -> np.ndarray:
    """Values (n,) mm, NaN for no value (see the module docstring).

    heights (n, k): the surface at each lit point; cos_tilt (n,): |cos| of the surface's
    tilt from horizontal at the spot centre; zero_z (n,): the sensor's zero (carriage z +
    its z offset); lost (n,) bool: no light back for another reason."""
    h = np.asarray(heights, dtype=float).mean(axis=1)
    cos = np.clip(np.abs(np.asarray(cos_tilt, dtype=float)), 1e-9, 1.0)
    tan2 = (1.0 - cos ** 2) / cos ** 2
    value = (h - np.asarray(zero_z, dtype=float) + slope_bias_mm * tan2) * (1.0 + scale_error)
    n = len(value)
    if noise_mm > 0:
        value = value + rng.normal(0.0, noise_mm, n)
    if resolution_mm > 0:
        value = np.round(value / resolution_mm) * resolution_mm
    gone = np.degrees(np.arccos(cos)) > acceptance_deg
    if lost is not None:
        gone = gone | np.asarray(lost, dtype=bool)
    if dropout_rate > 0:
        gone = gone | (rng.random(n) < dropout_rate)
    out: np.ndarray = np.where(gone, np.nan, value)
    return out
