"""The mock printhead's physics: the jetted material on the bed, drop by drop, and its cure.

The true surface is a height field on a regular grid of the head's pitch laid on the bed
(``origin_mm``: the centre of cell [0, 0]; rows along machine y, the scan axis; columns along
x).  A drop that lands at (x, y) adds a spherical cap of base diameter ``drop_diameter_um``
and its own volume to the cells around the nearest cell centre (the cap integrated over the
cells, supersampled, scaled to the drop's volume exactly).  Freshly landed ink is liquid;
when the UV lamp has cured it (:meth:`JettedField.cure`), liquid first flows by the
published threshold rule: between 4-neighbours whose surface heights differ by more than
``threshold_um``, flux ``mobility / 8 * (s_i - s_j)`` from high to low per sub-step, a cell
giving away at most the liquid it holds (cured ink does not move), then everything is
solid.  Volume is conserved to rounding.  Units: mm, mm^3 (1 pL = 1e-6 mm^3).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidConfig

MM3_PER_PL = 1e-6
SUPERSAMPLE = 9
EDGE_WEIGHT = 1.0 / 8.0


@dataclass(frozen=True)
class InkModel:
    """The ink on the substrate: drop size, and the threshold flow before the cure."""

    drop_diameter_um: float = 60.0
    threshold_um: float = 3.0
    mobility: float = 0.5
    flow_steps: int = 1

    def __post_init__(self) -> None:
        if not self.drop_diameter_um > 0 or not self.threshold_um >= 0 or not 0 <= self.mobility <= 1 \
                or not 0 <= self.flow_steps <= 100:
            raise InvalidConfig("ink: diameter > 0, threshold >= 0, mobility in [0, 1], flow_steps in 0..100",
                                field="port.ink", value=[self.drop_diameter_um, self.threshold_um, self.mobility,
                                                         self.flow_steps])


def cap_kernel(pitch_mm: float, diameter_um: float, volume_mm3: float = 1.0) -> np.ndarray:
    """(2k+1, 2k+1) heights (mm) one drop of ``volume_mm3`` adds around its cell.

    The spherical cap's apex h solves V = pi h (3 a^2 + h^2) / 6 (Newton from the flat-cap
    guess); the cap is averaged over ``SUPERSAMPLE``^2 points per cell and scaled so that
    ``kernel.sum() * pitch^2 == volume_mm3``."""
    a = diameter_um * 1e-3 / 2.0
    h = 2.0 * volume_mm3 / (math.pi * a * a)
    for _ in range(30):
        h -= (math.pi * h * (3 * a * a + h * h) / 6.0 - volume_mm3) / (math.pi * (a * a + h * h) / 2.0)
    r_sphere = (a * a + h * h) / (2.0 * h)
    k = max(int(math.ceil(a / pitch_mm + 0.5)) - 1, 0)
    side = (2 * k + 1) * SUPERSAMPLE
    u = ((np.arange(side) + 0.5) / SUPERSAMPLE - (k + 0.5)) * pitch_mm
    x, y = np.meshgrid(u, u, indexing="ij")
    r2 = x * x + y * y
    z = np.where(r2 < a * a, np.sqrt(np.maximum(r_sphere ** 2 - r2, 0.0)) - (r_sphere - h), 0.0)
    cells = z.reshape(2 * k + 1, SUPERSAMPLE, 2 * k + 1, SUPERSAMPLE).mean(axis=(1, 3))
    if cells.sum() <= 0.0:
        cells = np.zeros((2 * k + 1, 2 * k + 1))
        cells[k, k] = 1.0
    out: np.ndarray = cells * (volume_mm3 / (cells.sum() * pitch_mm ** 2))
    return out


def threshold_flow(surface: np.ndarray, liquid: np.ndarray, model: InkModel) -> np.ndarray:
    """The surface (L, W) mm after ``model.flow_steps`` sub-steps of the threshold flow of
    the ``liquid`` (L, W) mm on top of it (module docstring)."""
    s = np.array(surface, dtype=float)
    liq = np.maximum(np.array(liquid, dtype=float), 0.0)
    tau = model.threshold_um * 1e-3
    w = EDGE_WEIGHT * model.mobility
    for _ in range(model.flow_steps):
        flux_x = s[:, :-1] - s[:, 1:]     # from cell j to j+1 along a row (positive: rightwards)
        flux_y = s[:-1, :] - s[1:, :]
        flux_x = np.where(np.abs(flux_x) > tau, w * flux_x, 0.0)
        flux_y = np.where(np.abs(flux_y) > tau, w * flux_y, 0.0)
        leaving = np.zeros_like(s)
        leaving[:, :-1] += np.clip(flux_x, 0.0, None)
        leaving[:, 1:] += np.clip(-flux_x, 0.0, None)
        leaving[:-1, :] += np.clip(flux_y, 0.0, None)
        leaving[1:, :] += np.clip(-flux_y, 0.0, None)
        limit = np.where(leaving > liq, liq / np.where(leaving > 0, leaving, 1.0), 1.0)
        flux_x = np.where(flux_x > 0, flux_x * limit[:, :-1], flux_x * limit[:, 1:])
        flux_y = np.where(flux_y > 0, flux_y * limit[:-1, :], flux_y * limit[1:, :])
        change = np.zeros_like(s)
        change[:, :-1] -= flux_x
        change[:, 1:] += flux_x
        change[:-1, :] -= flux_y
        change[1:, :] += flux_y
        s += change
        liq = np.maximum(liq + change, 0.0)
    return s


class JettedField:
    """The material jetted on the bed: ``solid`` (L, W) and ``liquid`` (L, W) heights, mm,
    on cells of ``pitch_mm`` whose [0, 0] centre is at ``origin_mm`` (x, y)."""

    def __init__(self, origin_mm: tuple[float, float], pitch_mm: float, shape: tuple[int, int], ink: InkModel,
                 keep_history: bool = False) -> None:
        if not pitch_mm > 0 or shape[0] < 1 or shape[1] < 1 or shape[0] * shape[1] > 25_000_000:
            raise InvalidConfig("field: pitch > 0 and 1..25e6 cells", field="port.field", value=list(shape))
        self.origin = (float(origin_mm[0]), float(origin_mm[1]))
        self.pitch = float(pitch_mm)
        self.ink = ink
        self.solid = np.zeros(shape)
        self.liquid = np.zeros(shape)
        self.kernel = cap_kernel(self.pitch, ink.drop_diameter_um)  # per mm^3 of ink
        self.drops = 0
        self.volume_mm3 = 0.0
        self.cures = 0
        self.history: list[np.ndarray] | None = [] if keep_history else None
        self.lock = threading.Lock()

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.solid.shape[0]), int(self.solid.shape[1]))

    def cell_of(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Row and column (n,) of the cell nearest to each (x, y) (may lie outside)."""
        col = np.rint((np.asarray(x, dtype=float) - self.origin[0]) / self.pitch).astype(np.int64)
        row = np.rint((np.asarray(y, dtype=float) - self.origin[1]) / self.pitch).astype(np.int64)
        return row, col

    def land(self, x: np.ndarray, y: np.ndarray, volume_mm3: np.ndarray) -> int:
        """Drops (n,) landing at (x, y) mm with their volumes (mm^3); those off the field are
        lost, those of no volume (a dead nozzle's) never were.  Returns how many landed."""
        row, col = self.cell_of(x, y)
        k = self.kernel.shape[0] // 2
        ok = (row >= k) & (row < self.shape[0] - k) & (col >= k) & (col < self.shape[1] - k) \
            & (np.asarray(volume_mm3, dtype=float) > 0)
        volumes = np.zeros(self.shape)
        np.add.at(volumes, (row[ok], col[ok]), np.asarray(volume_mm3, dtype=float)[ok])
        if k == 0:
            added = volumes * float(self.kernel[0, 0])
        else:
            added = np.zeros(self.shape)
            for di in range(-k, k + 1):
                for dj in range(-k, k + 1):
                    weight = float(self.kernel[di + k, dj + k])
                    if weight:
                        added[k + di:self.shape[0] - k + di, k + dj:self.shape[1] - k + dj] += \
                            weight * volumes[k:self.shape[0] - k, k:self.shape[1] - k]
        with self.lock:
            self.liquid += added
            self.drops += int(ok.sum())
            self.volume_mm3 += float(np.asarray(volume_mm3, dtype=float)[ok].sum())
        return int(ok.sum())

    def cure(self) -> None:
        """The liquid flows (threshold rule) and becomes solid."""
        with self.lock:
            if self.liquid.any():
                self.solid = threshold_flow(self.solid + self.liquid, self.liquid, self.ink)
                self.liquid = np.zeros(self.shape)
            self.cures += 1
            if self.history is not None:
                self.history.append(self.solid.astype(np.float32))

    def heights(self) -> np.ndarray:
        """The surface now (L, W) mm above the bed (solid + liquid)."""
        with self.lock:
            out: np.ndarray = self.solid + self.liquid
        return out

    def top(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Height above the bed (n,) mm at xy (n, 2) (nearest cell) and whether xy is on the field."""
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        row, col = self.cell_of(p[:, 0], p[:, 1])
        half = 0.5 * self.pitch
        on = (p[:, 0] >= self.origin[0] - half) & (p[:, 1] >= self.origin[1] - half) \
            & (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])
        surface = self.heights()
        z = np.zeros(len(p))
        z[on] = surface[row[on], col[on]]
        return z, on
