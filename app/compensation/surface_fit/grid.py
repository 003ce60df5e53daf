"""Measurement grids: the probing plan over a region and the measured height grid.

Layout convention: ``z[i, j]`` is the height at ``(x[i], y[j])`` (``indexing="ij"``), so
axis 0 runs along x (the surface's u direction) and axis 1 along y (v).  Missing
measurements are NaN.  Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.compensation.surface_fit.errors import SurfaceFitError

__all__ = ["ProbeRegion", "ProbeGridPlan", "HeightGrid", "plan_probe_grid", "grid_from_plan"]


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
            raise SurfaceFitError("region needs finite x_min < x_max and y_min < y_max",
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


def plan_probe_grid(region: ProbeRegion, nx: int, ny: int) -> ProbeGridPlan:
    """Evenly spaced nx x ny probe grid over ``region`` (edges included), serpentine order."""
    for name, n in (("nx", nx), ("ny", ny)):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 2 <= n <= 1000:
            raise SurfaceFitError(f"{name} must be an integer in [2, 1000]",
                                  field=f"params.{name}", value=n)
    x = np.linspace(region.x_min, region.x_max, nx)
    y = np.linspace(region.y_min, region.y_max, ny)
    order = [(i, j) for i in range(nx) for j in (range(ny) if i % 2 == 0 else range(ny - 1, -1, -1))]
    index = np.array(order, dtype=int)
    return ProbeGridPlan(x=x, y=y, points_xy=np.column_stack([x[index[:, 0]], y[index[:, 1]]]),
                         index=index)


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
