"""Single-droplet height kernel D and the deposit operator B (the jetting MPC paper's eqs. 1-5).

A drop lands as a spherical cap of base diameter ``drop_diameter_um`` and volume
``drop_volume_pl``. The cap is integrated over the print cells (supersampled) and scaled
so that ``kernel.sum() * pitch**2 == volume`` exactly. ``B f`` is the convolution of the
drop pattern f (per-cell drop count or volume factor) with the kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .errors import JettingError
from .params import DropParams


@dataclass(frozen=True)
class DropKernel:
    """``heights_mm``: (2k+1, 2k+1) height added around the landing cell by one drop, mm;
    ``pitch_mm``: cell size; ``volume_mm3``: drop volume; ``cap_height_mm``: cap apex."""

    heights_mm: npt.NDArray[np.float64]
    pitch_mm: float
    volume_mm3: float
    cap_height_mm: float

    @property
    def radius_cells(self) -> int:
        """Half the kernel's side, cells."""
        return int(self.heights_mm.shape[0]) // 2

    @property
    def l1_radius(self) -> int:
        """Largest |di| + |dj| of a non-zero tap (a plus-shaped 3x3 kernel has 1)."""
        r = self.radius_cells
        di, dj = np.nonzero(self.heights_mm)
        return int((np.abs(di - r) + np.abs(dj - r)).max())

    def volume(self) -> float:
        """Volume the kernel deposits, mm^3 (== ``volume_mm3``)."""
        return float(self.heights_mm.sum() * self.pitch_mm**2)


def cap_height(radius_mm: float, volume_mm3: float) -> float:
    """Apex height h of a spherical cap with base radius a and volume V, mm.

    Solves V = pi h (3 a^2 + h^2) / 6 (monotone in h, one real root) in closed form.
    """
    a2 = radius_mm**2
    # depressed cubic h^3 + 3 a^2 h - 6 V / pi = 0 (Cardano, one real root)
    p, q = 3.0 * a2, -6.0 * volume_mm3 / np.pi
    disc = np.sqrt((q / 2.0) ** 2 + (p / 3.0) ** 3)
    h = float(np.cbrt(-q / 2.0 + disc) + np.cbrt(-q / 2.0 - disc))
    for _ in range(3):  # Newton polish: Cardano cancels digits when a^2 >> h^2
        h -= (h**3 + p * h + q) / (3.0 * h * h + p)
    return h


def drop_kernel(drop: DropParams) -> DropKernel:
    """Cell-integrated spherical-cap kernel for ``drop``; its volume equals the drop's."""
    if drop.dpi <= 0 or not np.isfinite(drop.dpi):
        raise JettingError("dpi must be a positive number", field="drop.dpi", value=drop.dpi)
    if drop.drop_diameter_um <= 0 or drop.drop_volume_pl <= 0:
        raise JettingError(
            "drop diameter and volume must be positive",
            field="drop.drop_diameter_um",
            value=[drop.drop_diameter_um, drop.drop_volume_pl],
        )
    pitch, a, vol = drop.pitch_mm, drop.radius_mm, drop.volume_mm3
    hc = cap_height(a, vol)
    sphere_r = (a * a + hc * hc) / (2.0 * hc)
    k = int(np.ceil(a / pitch + 0.5)) - 1
    s = drop.supersample
    offsets = (np.arange((2 * k + 1) * s) + 0.5) / s - (k + 0.5)  # cell units
    x, y = np.meshgrid(offsets * pitch, offsets * pitch, indexing="ij")
    r2 = x * x + y * y
    z = np.where(r2 < a * a, np.sqrt(np.maximum(sphere_r**2 - r2, 0.0)) - (sphere_r - hc), 0.0)
    cells = z.reshape(2 * k + 1, s, 2 * k + 1, s).mean(axis=(1, 3))
    if cells.sum() <= 0.0:  # drop far below one sub-sample: put it all in the centre
        cells = np.zeros((2 * k + 1, 2 * k + 1))
        cells[k, k] = 1.0
    heights = cells * (vol / (cells.sum() * pitch**2))
    return DropKernel(heights_mm=heights, pitch_mm=pitch, volume_mm3=vol, cap_height_mm=hc)


def deposit(drops: npt.NDArray[np.float64], kernel: DropKernel) -> npt.NDArray[np.float64]:
    """B f: heights (L, W) mm added by drops (L, W) (0/1 or per-drop volume factors).

    Drops within ``radius_cells`` of the grid border lose the part of the kernel that
    falls outside; targets keep a margin so this never happens on the part.
    """
    k = kernel.heights_mm
    if k.shape == (1, 1):
        return drops * float(k[0, 0])
    heights: npt.NDArray[np.float64] = ndimage.convolve(np.asarray(drops, dtype=float), k,  # scipy: untyped
                                    mode="constant", cval=0.0)
    return heights


def deposit_adjoint(heights: npt.NDArray[np.float64], kernel: DropKernel) -> npt.NDArray[np.float64]:
    """B^T y for y (L, W): correlation with the kernel (the exact transpose of ``deposit``)."""
    k = kernel.heights_mm
    if k.shape == (1, 1):
        return heights * float(k[0, 0])
    drops: npt.NDArray[np.float64] = ndimage.correlate(np.asarray(heights, dtype=float), k,  # scipy: untyped
                                   mode="constant", cval=0.0)
    return drops
