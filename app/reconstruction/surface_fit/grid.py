"""Measured height grids (surface fitting's input).

Layout convention: ``z[i, j]`` is the height at ``(x[i], y[j])`` (``indexing="ij"``), so
axis 0 runs along x (the surface's u direction) and axis 1 along y (v).  Missing
measurements are NaN.  Units: mm.  The grid of probes that measures one is planned by
:func:`app.probing.grid.plan_probe_grid`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.probing.grid import ProbeGridPlan
from app.reconstruction.surface_fit.errors import SurfaceFitError

__all__ = ["HeightGrid", "grid_from_plan"]


@dataclass(frozen=True)
class HeightGrid:
    """Measured heights z (nx, ny) at (x[i], y[j]); x (nx,), y (ny,) strictly increasing.
    NaN marks a missing measurement."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray

    def __post_init__(self) -> None:
        x, y = np.asarray(self.x, dtype=float), np.asarray(self.y, dtype=float)
        z = np.asarray(self.z, dtype=float)
        for name, axis in (("x", x), ("y", y)):
            if axis.ndim != 1 or axis.size < 2 or not np.isfinite(axis).all() or np.any(
                    np.diff(axis) <= 0):
                raise SurfaceFitError(f"grid.{name} must be a strictly increasing finite "
                                      "vector of at least 2 values", field=f"grid.{name}",
                                      value=axis.ravel()[:6])
        if z.shape != (x.size, y.size):
            raise SurfaceFitError(f"grid.z must have shape ({x.size}, {y.size}) = (len x, "
                                  f"len y), got {z.shape}", field="grid.z", value=list(z.shape))
        if np.isinf(z).any():
            bad = np.argwhere(np.isinf(z))[0]
            raise SurfaceFitError("grid.z contains an infinite height", field="grid.z",
                                  value={"i": int(bad[0]), "j": int(bad[1])})
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "z", z)

    @property
    def holes(self) -> np.ndarray:
        """(m, 2) int indices (i, j) of the missing heights."""
        return np.argwhere(np.isnan(self.z))

    def points(self) -> np.ndarray:
        """(k, 3) the measured (non-NaN) points, mm."""
        xx, yy = np.meshgrid(self.x, self.y, indexing="ij")
        ok = ~np.isnan(self.z)
        return np.column_stack([xx[ok], yy[ok], self.z[ok]])

    def as_point_grid(self) -> np.ndarray:
        """(nx, ny, 3) grid of points (requires no holes)."""
        xx, yy = np.meshgrid(self.x, self.y, indexing="ij")
        return np.stack([xx, yy, self.z], axis=-1)


def grid_from_plan(plan: ProbeGridPlan, z_measured: np.ndarray) -> HeightGrid:
    """Put heights measured in the plan's probing order (nx*ny,) into a HeightGrid
    (NaN for probes that failed)."""
    z_measured = np.asarray(z_measured, dtype=float).ravel()
    if z_measured.size != plan.index.shape[0]:
        raise SurfaceFitError(f"expected {plan.index.shape[0]} heights, got {z_measured.size}",
                              field="z", value=z_measured.size)
    z = np.full((plan.x.size, plan.y.size), np.nan)
    z[plan.index[:, 0], plan.index[:, 1]] = z_measured
    return HeightGrid(plan.x, plan.y, z)
