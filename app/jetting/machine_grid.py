"""The print grid on a machine: swaths for a head, the raster that scans a layer, the
measured map from the scan's samples, and the model's prediction where the scan saw nothing.

The grid (L, W) lies on the bed with the centre of cell [0, 0] at ``origin_mm`` (x, y);
rows run along +y (the scan axis the head fires on), columns along +x, both ``pitch_mm``
apart.  Pure numpy: positions in mm, heights in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from .errors import JettingError
from .flow import mobility_map
from .kernel import DropKernel
from .model import build_layer_model
from .params import FlowParams


@dataclass(frozen=True)
class Grid:
    """``shape`` (L, W) cells of ``pitch_mm``, cell [0, 0] centred at ``origin_mm`` (x, y)."""

    shape: tuple[int, int]
    pitch_mm: float
    origin_mm: tuple[float, float]

    def x(self, col: npt.ArrayLike) -> npt.NDArray[np.float64]:
        return self.origin_mm[0] + np.asarray(col, dtype=float) * self.pitch_mm

    def y(self, row: npt.ArrayLike) -> npt.NDArray[np.float64]:
        return self.origin_mm[1] + np.asarray(row, dtype=float) * self.pitch_mm


@dataclass(frozen=True)
class Swath:
    """One pass of the head: grid columns ``first_col`` .. ``first_col + bits.shape[1] - 1`` on
    nozzles 0 .. (``bits`` (L, count) bool: row i fires at grid row i)."""

    first_col: int
    bits: npt.NDArray[np.bool_]


def swaths(pattern: npt.NDArray[np.bool_], nozzles: int) -> list[Swath]:
    """The layer's 0/1 ``pattern`` (L, W) cut into swaths of at most ``nozzles`` columns
    (column j on nozzle j % nozzles, as the simulation's plant); swaths without a drop are
    left out."""
    if nozzles < 1:
        raise JettingError("the head needs at least one nozzle", field="nozzles", value=nozzles)
    p = np.asarray(pattern, dtype=bool)
    out = []
    for first in range(0, p.shape[1], nozzles):
        bits = p[:, first:first + nozzles]
        if bits.any():
            out.append(Swath(first, bits.copy()))
    return out


def raster_waypoints(grid: Grid, spot_offset_xy: tuple[float, float], z_mm: float,
                     run_in_cells: float = 1.5, cols: npt.NDArray[np.int64] | None = None) -> npt.NDArray[np.float64]:
    """Carriage waypoints (2n, 3) mm of a serpentine raster putting the sensor's spot
    (carriage + ``spot_offset_xy``) along the centre of each of the ``cols`` (n,) (default:
    all W), ``run_in_cells`` beyond the first and last row, at carriage height ``z_mm``."""
    cols = np.arange(grid.shape[1]) if cols is None else np.asarray(cols, dtype=np.int64)
    y_lo = float(grid.y(-run_in_cells)) - spot_offset_xy[1]
    y_hi = float(grid.y(grid.shape[0] - 1 + run_in_cells)) - spot_offset_xy[1]
    x = grid.x(cols) - spot_offset_xy[0]
    up = cols % 2 == 0
    start = np.where(up, y_lo, y_hi)
    end = np.where(up, y_hi, y_lo)
    w = np.empty((2 * len(cols), 3))
    w[0::2, 0], w[1::2, 0] = x, x
    w[0::2, 1], w[1::2, 1] = start, end
    w[:, 2] = z_mm
    return w


def cell_means(spot_xy: npt.NDArray[np.float64], heights_mm: npt.NDArray[np.float64], grid: Grid
               ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """The mean height (L, W) mm of the valid samples in each cell (NaN: none) and their
    count (L, W): samples (n,) at spot positions (n, 2), NaN heights are no value."""
    p = np.asarray(spot_xy, dtype=float).reshape(-1, 2)
    h = np.asarray(heights_mm, dtype=float)
    col = np.rint((p[:, 0] - grid.origin_mm[0]) / grid.pitch_mm).astype(np.int64)
    row = np.rint((p[:, 1] - grid.origin_mm[1]) / grid.pitch_mm).astype(np.int64)
    ok = np.isfinite(h) & (row >= 0) & (row < grid.shape[0]) & (col >= 0) & (col < grid.shape[1])
    flat = row[ok] * grid.shape[1] + col[ok]
    size = grid.shape[0] * grid.shape[1]
    count = np.bincount(flat, minlength=size)
    total = np.bincount(flat, weights=h[ok], minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return mean.reshape(grid.shape), count.reshape(grid.shape)


def predicted_heights(before_mm: npt.NDArray[np.float64], pattern: npt.NDArray[np.bool_], kernel: DropKernel,
                      flow: FlowParams, model: str = "transport") -> npt.NDArray[np.float64]:
    """The controller's model of the surface (L, W) mm after printing ``pattern`` on
    ``before_mm`` (drops deposited, the flow of that pattern, flat substrate)."""
    drops = np.asarray(pattern, dtype=float)
    before = np.asarray(before_mm, dtype=float)
    layer = build_layer_model(before, drops, kernel, flow, mobility_map(np.zeros(before.shape), flow), model)
    out: npt.NDArray[np.float64] = before + layer.apply(drops)
    return out


def fill_missing(measured_mm: npt.NDArray[np.float64], predicted_mm: npt.NDArray[np.float64]
                 ) -> tuple[npt.NDArray[np.float64], int]:
    """``measured_mm`` (L, W) with its NaN cells (no valid sample: a dropout) taken from
    ``predicted_mm`` (L, W); and how many cells were filled."""
    m = np.asarray(measured_mm, dtype=float)
    missing = ~np.isfinite(m)
    out: npt.NDArray[np.float64] = np.where(missing, np.asarray(predicted_mm, dtype=float), m)
    return out, int(missing.sum())


def substrate_map(heights_mm: npt.NDArray[np.float64], pitch_mm: float, sigma_mm: float = 0.5
                  ) -> npt.NDArray[np.float64]:
    """The substrate (L, W) mm from its scan (NaN: no sample): its best plane plus the rest
    smoothed by a Gaussian of ``sigma_mm`` over the cells that have a sample (normalised convolution: a cell without
    one takes its neighbourhood's weighted mean).  A substrate is smooth at that scale; the
    sensor's noise would otherwise be a fixed pattern in every layer's map.  ``JettingError``
    when the scan saw nothing."""
    h = np.asarray(heights_mm, dtype=float)
    seen = np.isfinite(h)
    if not seen.any():
        raise JettingError("the sensor saw nothing of the substrate under the grid", field="origin_mm", value=None)
    rows, cols = np.indices(h.shape, dtype=float)
    basis = np.stack([np.ones(h.shape), rows, cols], axis=-1)  # a plane first: no tilt bias at the edges
    coef = np.linalg.lstsq(basis[seen], h[seen], rcond=None)[0]
    plane = basis @ coef
    sigma = sigma_mm / pitch_mm
    total = ndimage.gaussian_filter(np.where(seen, h - plane, 0.0), sigma, mode="nearest")  # scipy: untyped
    weight = ndimage.gaussian_filter(seen.astype(float), sigma, mode="nearest")
    out: npt.NDArray[np.float64] = plane + np.where(weight > 1e-9, total / np.maximum(weight, 1e-9), 0.0)
    return out
