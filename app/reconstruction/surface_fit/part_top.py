"""The nominal part's top surface as a fitted NURBS surface (no measurement: the CAD top
sampled by vertical rays on a probing grid, then :func:`fit_surface`)."""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.drape import top_surface_z
from app.probing.grid import ProbeGridPlan
from app.reconstruction.surface_fit.fit import SurfaceFit, SurfaceFitParams, fit_surface
from app.reconstruction.surface_fit.grid import grid_from_plan


def sample_nominal_grid(mesh: trimesh.Trimesh, plan: ProbeGridPlan) -> np.ndarray:
    """Nominal heights (nu*nv,) of the plan's probe points on the part's top, probing order
    (NaN where a vertical ray misses the part)."""
    return top_surface_z(mesh, plan.points_xy).z


def fit_part_top(mesh: trimesh.Trimesh, plan: ProbeGridPlan, fit_params: SurfaceFitParams) -> SurfaceFit:
    """Fit the part's nominal top surface sampled at the plan's grid."""
    return fit_surface(grid_from_plan(plan, sample_nominal_grid(mesh, plan)), fit_params)
