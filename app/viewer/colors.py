"""Colours of the 3D view: a fixed palette and two colour maps (uint8 RGB).

Deviation uses a diverging blue-white-red map symmetric about zero (blue: below the
nominal, red: above); heights use a perceptually ordered dark-blue -> yellow ramp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RGB = tuple[int, int, int]


@dataclass(frozen=True)
class Palette:
    """Colours of the scene elements (RGB 0..255)."""

    mesh: RGB = (104, 118, 138)  # slate: shaded contrast against the white grid (was a pale (176, 186, 198))
    nominal: RGB = (40, 120, 220)
    reconstructed: RGB = (230, 120, 20)
    planned: RGB = (60, 60, 70)
    dispense: RGB = (220, 40, 60)
    travel: RGB = (150, 160, 175)
    compensated: RGB = (20, 170, 90)
    layers: RGB = (120, 140, 170)
    current_layer: RGB = (230, 100, 20)
    tool_axis: RGB = (130, 60, 200)


PALETTE = Palette()

# Anchor colours of the maps (positions 0..1).
_DIVERGING = np.array([[33, 102, 172], [247, 247, 247], [178, 24, 43]], dtype=float)
_RAMP = np.array([[48, 18, 59], [40, 110, 200], [30, 190, 150], [190, 220, 60], [250, 240, 30]], dtype=float)


def _stops(anchors: np.ndarray) -> tuple[tuple[float, str], ...]:
    """The anchors as legend gradient stops [(position 0..1, "#rrggbb")]."""
    grid = np.linspace(0.0, 1.0, len(anchors))
    return tuple((float(t), "#{:02x}{:02x}{:02x}".format(*(int(round(c)) for c in rgb)))
                 for t, rgb in zip(grid, anchors))


DIVERGING_STOPS = _stops(_DIVERGING)
RAMP_STOPS = _stops(_RAMP)


def _interpolate(anchors: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Piecewise-linear colour map: t (n,) in [0, 1] -> (n, 3) uint8."""
    t = np.clip(np.nan_to_num(np.asarray(t, dtype=float), nan=0.5), 0.0, 1.0)
    grid = np.linspace(0.0, 1.0, len(anchors))
    out = np.stack([np.interp(t, grid, anchors[:, k]) for k in range(3)], axis=-1)
    return np.rint(out).astype(np.uint8)


def deviation_colors(deviation_mm: np.ndarray, limit_mm: float | None = None) -> np.ndarray:
    """Diverging colours for signed deviations (n,) mm -> (n, 3) uint8.

    ``limit_mm`` (default: the largest |deviation|) maps to full blue/red; zero is white.
    """
    dev = np.asarray(deviation_mm, dtype=float).reshape(-1)
    if limit_mm is None:
        finite = np.abs(dev[np.isfinite(dev)])
        limit_mm = float(finite.max()) if finite.size else 0.0
    if limit_mm <= 0.0:
        return _interpolate(_DIVERGING, np.full(dev.shape, 0.5))
    return _interpolate(_DIVERGING, 0.5 + 0.5 * dev / limit_mm)


def height_colors(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Sequential colours for values (n,) between ``lo`` and ``hi`` -> (n, 3) uint8."""
    v = np.asarray(values, dtype=float).reshape(-1)
    span = hi - lo
    t = np.full(v.shape, 0.5) if span <= 0 else (v - lo) / span
    return _interpolate(_RAMP, t)
