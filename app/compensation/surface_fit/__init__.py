"""Surface measurement plan, preprocessing (bad points, densification, smoothing) and
NURBS surface fit of a measured part (seed S3, step 1)."""

from app.compensation.surface_fit.errors import GridHoleError, SurfaceFitError
from app.compensation.surface_fit.fit import SurfaceFit, SurfaceFitParams, fit_surface
from app.compensation.surface_fit.grid import (
    HeightGrid,
    ProbeGridPlan,
    ProbeRegion,
    grid_from_plan,
    plan_probe_grid,
)
from app.compensation.surface_fit.part_top import fit_part_top, sample_nominal_grid

__all__ = [
    "GridHoleError", "HeightGrid", "ProbeGridPlan", "ProbeRegion", "SurfaceFit",
    "SurfaceFitError", "SurfaceFitParams", "fit_part_top", "fit_surface", "grid_from_plan", "plan_probe_grid",
    "sample_nominal_grid",
]
