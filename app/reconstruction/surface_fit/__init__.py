"""Measured height grids, preprocessing (bad points, densification, smoothing) and NURBS
surface fit of a measured part (the EHD patent, step 1).  The probe grid that measures one is
planned in :mod:`app.probing.grid`."""

from app.reconstruction.surface_fit.errors import GridHoleError, SurfaceFitError
from app.reconstruction.surface_fit.fit import SurfaceFit, SurfaceFitParams, fit_surface
from app.reconstruction.surface_fit.grid import HeightGrid, grid_from_plan
from app.reconstruction.surface_fit.part_top import fit_part_top, sample_nominal_grid

__all__ = [
    "GridHoleError", "HeightGrid", "SurfaceFit", "SurfaceFitError", "SurfaceFitParams", "fit_part_top",
    "fit_surface", "grid_from_plan",
    "sample_nominal_grid",
]
