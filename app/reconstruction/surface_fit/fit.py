"""Measured points -> preprocessed grid -> NURBS surface, with residuals (the EHD patent, step 1).

``fit_surface(data, params)`` accepts a :class:`HeightGrid` (probing grid, NaN = missing)
or CMM points (k, 3).  Pipeline:

grid:   holes? (policy "error" -> GridHoleError naming the cells; "fill" -> filled) ->
        bad-point removal (removed points are refilled by interpolation) -> densify ->
        smoothing -> interpolating or least-squares NURBS fit of the grid;
points: bad-point removal -> either a least-squares fit of the scattered points directly
        (x, y parametrisation: the part seen from above), or, with ``resample_shape``, a
        thin-plate resampling onto a grid (densification) and the grid pipeline.

Residuals are the distances of the kept measured points to the fitted surface (closest
point, surface inversion), signed positive above the surface.  The least-squares control
net size is chosen by generalised cross-validation when not given.  Degenerate data
(too few distinct (x, y) positions, positions on one line, repeated positions where
resampling needs one height per position, a singular fit) raise SurfaceFitError naming
the field.  Units: mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from annotated_types import Ge, Gt, Le

from app.domain.checks import require_declared_bounds
from app.geometry.errors import GeometryError
from app.geometry.fitting import fit_surface as lsq_surface
from app.geometry.fitting import interpolate_surface
from app.geometry.nurbs_surface import NurbsSurface
from app.reconstruction.surface_fit.errors import GridHoleError, SurfaceFitError
from app.reconstruction.surface_fit.grid import HeightGrid
from app.reconstruction.surface_fit.preprocess import (
    check_point_spread,
    choose_control_count,
    densify_grid,
    fill_holes,
    find_bad_points,
    interpolate_heights,
    smooth_grid,
    square_shape,
)

__all__ = ["SurfaceFitParams", "SurfaceFit", "fit_surface"]

Smoothing = Literal["none", "moving_average", "five_point_cubic", "spline"]
FitMethod = Literal["least_squares", "interpolate"]
HolePolicy = Literal["error", "fill"]


@dataclass(frozen=True)
class SurfaceFitParams:
    """How to preprocess and fit.

    method: "least_squares" or "interpolate"; degree: of both directions.
    control_points: (n_u, n_v) for least squares, None = choose by GCV.
    penalty: second-difference smoothing weight of the least-squares fit (0 = plain).
    smoothing: "none" | "moving_average" | "five_point_cubic" | "spline" (grids only);
    moving_average_window: odd window; smoothing_passes: repetitions.
    remove_bad_points, bad_point_sigma, bad_point_min_mm: outlier removal.
    hole_policy: "error" (NaN heights in the input are an error) or "fill".
    densify_factor: grid refinement factor (>= 1) before smoothing/fit.
    resample_shape: (nx, ny) to resample scattered points onto a grid (None: fit directly).
    The bounds in the annotations are the ranges a fit may ask for (the surface_fit job's
    parameter model reads them); a value outside them is refused here too.
    """

    method: FitMethod = "least_squares"
    degree: Annotated[int, Ge(1), Le(5)] = 3
    control_points: tuple[int, int] | None = None
    penalty: Annotated[float, Ge(0), Le(1e6)] = 0.0
    smoothing: Smoothing = "none"
    moving_average_window: Annotated[int, Ge(1), Le(15)] = 3
    smoothing_passes: Annotated[int, Ge(1), Le(20)] = 1
    remove_bad_points: bool = True
    bad_point_sigma: Annotated[float, Gt(0), Le(100)] = 5.0
    bad_point_min_mm: Annotated[float, Ge(0), Le(10)] = 0.01
    hole_policy: HolePolicy = "error"
    densify_factor: Annotated[int, Ge(1), Le(8)] = 1
    resample_shape: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        require_declared_bounds(self, SurfaceFitError, prefix="params.")
        checks = [
            ("method", self.method in ("least_squares", "interpolate")),
            ("degree", isinstance(self.degree, int)),
            ("smoothing", self.smoothing in ("none", "moving_average", "five_point_cubic",
                                             "spline")),
            ("moving_average_window", isinstance(self.moving_average_window, int)
             and self.moving_average_window % 2 == 1),
            ("smoothing_passes", isinstance(self.smoothing_passes, int)),
            ("hole_policy", self.hole_policy in ("error", "fill")),
            ("densify_factor", isinstance(self.densify_factor, int)),
            ("control_points", self.control_points is None or (
                len(self.control_points) == 2
                and all(isinstance(n, int) and n > self.degree for n in self.control_points))),
            ("resample_shape", self.resample_shape is None or (
                len(self.resample_shape) == 2
                and all(isinstance(n, int) and 4 <= n <= 1000 for n in self.resample_shape))),
        ]
        for name, ok in checks:
            if not ok:
                value = getattr(self, name)
                raise SurfaceFitError(f"invalid surface-fit parameter {name}: {value!r}",
                                      field=f"params.{name}",
                                      value=list(value) if isinstance(value, tuple) else value)


@dataclass(frozen=True)
class SurfaceFit:
    """A fitted surface and how well it matches the measurement.

    surface: the NURBS surface (mm); residuals_mm: (k,) signed distances of the kept
    measured points to it; residual_max_mm / residual_rms_mm: their max |.| and RMS;
    removed_points: (m, 3) points removed as bad; filled_holes: count of missing heights
    filled; control_points: (n_u, n_v) of the surface; fitted_grid: the preprocessed grid
    that was fitted (None for a direct scattered fit); method, smoothing: what was done.
    """

    surface: NurbsSurface
    residuals_mm: np.ndarray
    residual_max_mm: float
    residual_rms_mm: float
    removed_points: np.ndarray
    filled_holes: int
    control_points: tuple[int, int]
    fitted_grid: HeightGrid | None
    method: str
    smoothing: str

    def summary(self) -> dict[str, Any]:
        """JSON-friendly metrics for a job result."""
        return {"method": self.method, "smoothing": self.smoothing,
                "control_points": list(self.control_points),
                "residual_max_mm": self.residual_max_mm,
                "residual_rms_mm": self.residual_rms_mm,
                "removed_points": self.removed_points.tolist(),
                "filled_holes": self.filled_holes, "points": int(self.residuals_mm.size)}


def _signed_residuals(surface: NurbsSurface, points: np.ndarray) -> np.ndarray:
    inv = surface.invert(points)
    n = surface.normal(inv.u, inv.v)
    n *= np.where(n[:, 2:3] < 0, -1.0, 1.0)
    side = np.sign(np.einsum("ij,ij->i", points - inv.closest, n))
    out: np.ndarray = np.where(side == 0, 1.0, side) * inv.distance
    return out


def _fit_grid(grid: HeightGrid, params: SurfaceFitParams) -> tuple[NurbsSurface, tuple[int, int]]:
    g = grid.as_point_grid()
    if params.method == "interpolate":
        return interpolate_surface(g, params.degree, params.degree), g.shape[:2]
    size = params.control_points or choose_control_count(g, params.degree, params.penalty,
                                                         g.shape[:2])
    if size[0] > g.shape[0] or size[1] > g.shape[1]:
        raise SurfaceFitError(f"control net {list(size)} larger than the grid "
                              f"{list(g.shape[:2])}", field="params.control_points",
                              value=list(size))
    return lsq_surface(g, size[0], size[1], params.degree, params.degree,
                       params.penalty).surface, size


def _check_holes(grid: HeightGrid, params: SurfaceFitParams) -> None:
    holes = grid.holes
    if holes.size and params.hole_policy == "error":
        raise GridHoleError(
            f"the measurement grid has {holes.shape[0]} missing (NaN) heights, first at "
            f"(i={holes[0, 0]}, j={holes[0, 1]}); re-probe them or set hole_policy='fill'",
            field="grid.z", value={"missing": int(holes.shape[0]),
                                   "cells": holes[:6].tolist()})
    if holes.shape[0] > 0.5 * grid.z.size:
        raise GridHoleError(f"{holes.shape[0]} of {grid.z.size} heights are missing: too "
                            "few to fill", field="grid.z", value=int(holes.shape[0]))


def fit_surface(data: HeightGrid | np.ndarray, params: SurfaceFitParams) -> SurfaceFit:
    """Fit a NURBS surface to a measured grid or to CMM points (k,3) (see module doc).

    Raises GridHoleError (NaN heights with hole_policy "error"), SurfaceFitError (bad
    shapes, too few distinct (x, y) positions, positions on one line, repeated positions
    with ``resample_shape``, a net larger than the data or a singular fit).
    """
    try:
        return _fit_surface(data, params)  # one BLAS thread: set once per job process (CONFORMA_BLAS_THREADS)
    except GeometryError as exc:  # the geometry core's fits: report as this package's error
        field = exc.field or "points"
        if field.startswith("n_ctrl"):
            field = "params.control_points"
        raise SurfaceFitError(exc.message, field=field, value=exc.value) from None
    except np.linalg.LinAlgError as exc:  # a last resort: every known case is checked first
        raise SurfaceFitError(f"the surface fit is singular for these data: {exc}",
                              field="points" if not isinstance(data, HeightGrid) else "grid.z",
                              value=None) from None


def _fit_surface(data: HeightGrid | np.ndarray, params: SurfaceFitParams) -> SurfaceFit:
    if isinstance(data, HeightGrid):
        grid, points = data, None
        _check_holes(grid, params)
        measured = grid.points()
    else:
        points = np.asarray(data, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise SurfaceFitError("points must be a finite (k, 3) array in mm",
                                  field="points", value=list(points.shape))
        # the bad-point detection fits a height surface of its own: twice the unknowns
        per_patch = (params.degree + 1) ** 2 * (2 if params.remove_bad_points else 1)
        check_point_spread(points, per_patch, field="points",
                           unique=params.resample_shape is not None)
        measured = points
    removed = np.zeros((0, 3))
    if params.remove_bad_points:
        bad = find_bad_points(measured, k_sigma=params.bad_point_sigma,
                              min_mm=params.bad_point_min_mm, degree=params.degree,
                              field="points" if points is not None else "grid.z").bad
        removed, measured = measured[bad], measured[~bad]
    filled = 0
    fitted_grid: HeightGrid | None = None
    if points is None or params.resample_shape is not None:
        if points is None:
            z = grid.z.copy()
            xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
            for p in removed:
                z[(xx == p[0]) & (yy == p[1])] = np.nan
            base = HeightGrid(grid.x, grid.y, z)
        else:
            assert params.resample_shape is not None  # the branch's condition
            nx, ny = params.resample_shape
            lo, hi = measured[:, :2].min(axis=0), measured[:, :2].max(axis=0)
            base = HeightGrid(np.linspace(lo[0], hi[0], nx), np.linspace(lo[1], hi[1], ny),
                              np.full((nx, ny), np.nan))
            base = HeightGrid(base.x, base.y, _resample(measured, base))
        filled = int(np.isnan(base.z).sum())
        fitted_grid = smooth_grid(densify_grid(fill_holes(base, params.degree), params.densify_factor),
                                  params.smoothing, window=params.moving_average_window,
                                  passes=params.smoothing_passes)
        surface, size = _fit_grid(fitted_grid, params)
    else:
        size = params.control_points or choose_control_count(
            measured, params.degree, params.penalty, square_shape(measured.shape[0]))
        surface = lsq_surface(measured, size[0], size[1], params.degree, params.degree,
                              params.penalty).surface
    residuals = _signed_residuals(surface, measured)
    return SurfaceFit(surface=surface, residuals_mm=residuals,
                      residual_max_mm=float(np.abs(residuals).max()),
                      residual_rms_mm=float(np.sqrt(np.mean(residuals**2))),
                      removed_points=removed, filled_holes=filled,
                      control_points=(int(size[0]), int(size[1])), fitted_grid=fitted_grid,
                      method=params.method, smoothing=params.smoothing)


def _resample(points: np.ndarray, grid: HeightGrid) -> np.ndarray:
    """Interpolated heights of scattered points at the grid nodes (nx, ny)."""
    xx, yy = np.meshgrid(grid.x, grid.y, indexing="ij")
    return interpolate_heights(points, np.column_stack([xx.ravel(), yy.ravel()])).reshape(xx.shape)
