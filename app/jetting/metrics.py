"""Surface metrics of a printed layer over the part's cells (the jetting MPC paper, section 3.2).

Sa = mean |h - mean h|, Sz = max h - min h, RMSE (eq. 16) = sqrt(mean (h - mean h)^2),
all over the part mask (``sa_interior_um``: Sa of the interior cells alone). Edge
collapse = mean height of the interior cells minus the mean height of the edge cells
(outer edge, hole edge, and both together). Heights in mm, metrics out in um.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .targets import Target

UM_PER_MM = 1e3


@dataclass(frozen=True)
class SurfaceMetrics:
    """Metrics of one height map over the part, um."""

    sa_um: float
    sa_interior_um: float
    sz_um: float
    rmse_um: float
    edge_collapse_um: float
    edge_collapse_outer_um: float
    edge_collapse_hole_um: float
    mean_height_um: float
    target_height_um: float

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items()}


def _collapse(heights: npt.NDArray[np.float64], interior_mean: float, edge: npt.NDArray[np.bool_]) -> float:
    """Interior mean height minus the mean over the ``edge`` cells (0 without any), mm."""
    return float(interior_mean - heights[edge].mean()) if edge.any() else 0.0


def surface_metrics(heights_mm: npt.NDArray[np.float64], target: Target,
                    target_height_mm: float) -> SurfaceMetrics:
    """Metrics of heights (L, W) mm over ``target.mask``; ``target_height_mm`` is the reference."""
    h = np.asarray(heights_mm, dtype=float)
    part = h[target.mask]
    mean = float(part.mean())
    dev = part - mean
    interior_mean = float(h[target.interior].mean())
    both = target.outer_edge | target.hole_edge
    return SurfaceMetrics(
        sa_um=float(np.abs(dev).mean()) * UM_PER_MM,
        sa_interior_um=float(np.abs(h[target.interior] - interior_mean).mean()) * UM_PER_MM,
        sz_um=float(part.max() - part.min()) * UM_PER_MM,
        rmse_um=float(np.sqrt(np.mean(dev * dev))) * UM_PER_MM,
        edge_collapse_um=_collapse(h, interior_mean, both) * UM_PER_MM,
        edge_collapse_outer_um=_collapse(h, interior_mean, target.outer_edge) * UM_PER_MM,
        edge_collapse_hole_um=_collapse(h, interior_mean, target.hole_edge) * UM_PER_MM,
        mean_height_um=mean * UM_PER_MM,
        target_height_um=float(target_height_mm) * UM_PER_MM,
    )
