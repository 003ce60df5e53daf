"""Probe grids over a region of a part: where to touch when a surface is measured (pure).

:func:`plan_probe_grid` spaces nx x ny probes evenly over a :class:`ProbeRegion` (edges
included) in serpentine order; the heights measured there become a
:class:`app.reconstruction.surface_fit.grid.HeightGrid` (``grid_from_plan``).  Layout
convention: probe ``k`` sits at ``(x[i], y[j])`` with ``(i, j) = index[k]``.  Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.domain.errors import InvalidInput

__all__ = ["ProbeGridError", "ProbeRegion", "ProbeGridPlan", "plan_probe_grid"]


class ProbeGridError(InvalidInput):
    """A probe region or grid size that cannot be planned (422), naming the field."""


@dataclass(frozen=True)
class ProbeRegion:
    """Axis-aligned rectangle of the part to measure (mm)."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def __post_init__(self) -> None:
        vals = (self.x_min, self.x_max, self.y_min, self.y_max)
        if not all(np.isfinite(v) for v in vals) or not (
                self.x_max > self.x_min and self.y_max > self.y_min):
            raise ProbeGridError("region needs finite x_min < x_max and y_min < y_max",
                                 field="region", value=list(vals))


@dataclass(frozen=True)
class ProbeGridPlan:
    """An nx x ny probing grid.

    x: (nx,), y: (ny,) grid lines (mm); points_xy: (nx*ny, 2) probe positions in probing
    order (serpentine: every other x column runs backwards, so travel is short);
    index: (nx*ny, 2) the (i, j) grid cell of each probe.
    """

    x: np.ndarray
    y: np.ndarray
    points_xy: np.ndarray
    index: np.ndarray


def plan_probe_grid(region: ProbeRegion, nx: int, ny: int) -> ProbeGridPlan:
    """Evenly spaced nx x ny probe grid over ``region`` (edges included), serpentine order."""
    for name, n in (("nx", nx), ("ny", ny)):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 2 <= n <= 1000:
            raise ProbeGridError(f"{name} must be an integer in [2, 1000]",
                                 field=f"params.{name}", value=n)
    x = np.linspace(region.x_min, region.x_max, nx)
    y = np.linspace(region.y_min, region.y_max, ny)
    order = [(i, j) for i in range(nx) for j in (range(ny) if i % 2 == 0 else range(ny - 1, -1, -1))]
    index = np.array(order, dtype=int)
    return ProbeGridPlan(x=x, y=y, points_xy=np.column_stack([x[index[:, 0]], y[index[:, 1]]]),
                         index=index)
