"""Nozzle body clearance: how close a flat-ended cylinder of outer diameter D comes to the part.

The nozzle body is a vertical flat-ended cylinder with its tip at the bottom (SPEC16).  At a
tip position p the clearance is ``p_z - max{h(q) : |q - p_xy| <= D/2}``: on a slope theta
under a tip at standoff s it is ``s - (D/2) tan(theta)``, smaller than the tip's standoff.

The disc is sampled: its centre, ``rings`` concentric rings of ``per_ring`` points (the
outer one on the rim), then ``per_ring`` more rim points spread over one sampling step either
side of the highest rim point, plus the peak of the sinusoid through that point and its two
rim neighbours.  On a plane the maximum is on the rim and the rim height is a sinusoid in
the angle, so the result is exact there (to rounding); on a curved surface the refined rim
samples are at most ``2 pi / (per_ring (per_ring - 1))`` apart in angle, and a compass search
(14 halvings from half the ring spacing, kept inside the disc) then climbs from the highest
sample to the local maximum.  A second, separate peak narrower than the ring spacing
(D / 2 / rings) lying between samples can still be missed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.calibration.errors import CalibrationError

__all__ = ["Clearance", "nozzle_clearance"]


@dataclass(frozen=True)
class Clearance:
    """min_mm: the smallest clearance (mm, negative = the body cuts into the part); index: the tip
    where it occurs; point_mm (3,): the surface point the body comes closest to there;
    per_point_mm (n,): each tip's clearance (mm)."""

    min_mm: float
    index: int
    point_mm: tuple[float, float, float]
    per_point_mm: npt.NDArray[np.float64]


def nozzle_clearance(tips: npt.ArrayLike, height_at: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]],
                     outer_diameter_mm: float, *,
                     rings: int = 3, per_ring: int = 16) -> Clearance:
    """Clearance of the nozzle body at tip positions (n, 3) mm over the surface ``height_at``.

    height_at: vectorised surface height, (k, 2) xy mm -> (k,) z mm (called twice).
    """
    p = np.asarray(tips, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise CalibrationError("tips must have shape (n, 3) with n >= 1 (mm)", field="tips", value=list(p.shape))
    if not np.isfinite(p).all():
        raise CalibrationError("tips must be finite", field="tips")
    radius = float(outer_diameter_mm) / 2
    if not np.isfinite(radius) or radius < 0:
        raise CalibrationError("outer_diameter_mm must be >= 0", field="outer_diameter_mm", value=outer_diameter_mm)
    if rings < 1 or per_ring < 3:
        raise CalibrationError("need rings >= 1 and per_ring >= 3", field="rings", value=[rings, per_ring])
    n = len(p)
    angles = 2 * np.pi * np.arange(per_ring) / per_ring
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    radii = radius * np.arange(1, rings + 1) / rings
    disc = np.concatenate([[[0.0, 0.0]], (radii[:, None, None] * unit[None]).reshape(-1, 2)])   # (m, 2)
    h = _heights(height_at, p[:, None, :2] + disc[None], n)                                   # (n, m)
    # refine around each tip's highest rim sample
    rim = h[:, 1 + (rings - 1) * per_ring:]
    j = np.argmax(rim, axis=1)
    best = angles[j]                                                                            # (n,)
    step = 2 * np.pi / per_ring
    # the rim height of a plane is C + A cos(phi) + B sin(phi): three rim samples fix its maximum
    trio = np.stack([rim[np.arange(n), (j + s) % per_ring] for s in (-1, 0, 1)], axis=1)       # (n, 3)
    phis = best[:, None] + step * np.array([-1.0, 0.0, 1.0])[None]
    basis = np.stack([np.ones_like(phis), np.cos(phis), np.sin(phis)], axis=2)                 # (n, 3, 3)
    coef = np.linalg.solve(basis, trio[:, :, None])[:, :, 0]
    peak = np.arctan2(coef[:, 2], coef[:, 1])
    peak = best + np.clip(np.angle(np.exp(1j * (peak - best))), -step, step)
    spread = step * (np.arange(per_ring) / (per_ring - 1) * 2 - 1)[None]
    fine = np.concatenate([best[:, None] + spread, peak[:, None]], axis=1)                    # (n, per_ring + 1)
    fine_xy = p[:, None, :2] + radius * np.stack([np.cos(fine), np.sin(fine)], axis=2)
    h_fine = _heights(height_at, fine_xy, n)
    all_xy = np.concatenate([p[:, None, :2] + disc[None], fine_xy], axis=1)
    all_h = np.concatenate([h, h_fine], axis=1)
    k = np.argmax(all_h, axis=1)
    best_xy, top = all_xy[np.arange(n), k], all_h[np.arange(n), k]
    best_xy, top = _climb(height_at, p[:, :2], best_xy, top, radius, radius / rings / 2)
    per_point = p[:, 2] - top
    i = int(np.argmin(per_point))
    x, y = best_xy[i]
    return Clearance(min_mm=float(per_point[i]), index=i, point_mm=(float(x), float(y), float(top[i])),
                     per_point_mm=per_point)


def _climb(height_at: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]], centres: npt.NDArray[np.float64],
           xy: npt.NDArray[np.float64], top: npt.NDArray[np.float64],
           radius: float, step: float, iterations: int = 14) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Compass search for each disc's highest point from its best sample, kept inside the disc."""
    n = len(xy)
    compass = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-1, 1], [-1, -1]]) / np.array(
        [1, 1, 1, 1, math.sqrt(2), math.sqrt(2), math.sqrt(2), math.sqrt(2)])[:, None]
    steps = np.full(n, step)
    for _ in range(iterations):
        cand = xy[:, None, :] + steps[:, None, None] * compass[None]                   # (n, 8, 2)
        rel = cand - centres[:, None, :]
        dist = np.linalg.norm(rel, axis=2, keepdims=True)
        cand = centres[:, None, :] + rel * np.minimum(1.0, radius / np.maximum(dist, 1e-300))
        h = _heights(height_at, cand, n)
        j = np.argmax(h, axis=1)
        better = h[np.arange(n), j] > top
        xy = np.where(better[:, None], cand[np.arange(n), j], xy)
        top = np.where(better, h[np.arange(n), j], top)
        steps = np.where(better, steps, steps / 2)
    return xy, top


def _heights(height_at: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]], xy: npt.NDArray[np.float64],
             n: int) -> npt.NDArray[np.float64]:
    flat = xy.reshape(-1, 2)
    z = np.asarray(height_at(flat), dtype=float).reshape(-1)
    if z.shape != (len(flat),):
        raise CalibrationError(f"height_at returned {z.shape[0]} heights for {len(flat)} points", field="height_at")
    if not np.isfinite(z).all():
        j = int(np.flatnonzero(~np.isfinite(z))[0])
        raise CalibrationError("the surface has no height under part of the nozzle body",
                               field="height_at", value=flat[j])
    return z.reshape(n, -1)
