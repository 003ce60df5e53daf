"""The nominal top of a part mesh, sampled on a probing grid and fitted (truth: a tilted plane)."""

from __future__ import annotations

import numpy as np
import trimesh

from app.probing.grid import ProbeRegion, plan_probe_grid
from app.reconstruction.surface_fit import SurfaceFitParams, fit_part_top, sample_nominal_grid


def _plane(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 5.0 + 0.1 * x - 0.05 * y


def _tilted_block() -> trimesh.Trimesh:
    """A 40 x 40 mm block whose top is the plane above (bottom at z = 0)."""
    box = trimesh.creation.box(extents=(40.0, 40.0, 1.0))
    vertices = box.vertices.copy()
    top = vertices[:, 2] > 0
    vertices[top, 2] = _plane(vertices[top, 0], vertices[top, 1])
    vertices[~top, 2] = 0.0
    return trimesh.Trimesh(vertices, box.faces, process=False)


def test_the_grid_samples_the_top_and_misses_off_the_part():
    plan = plan_probe_grid(ProbeRegion(-10.0, 25.0, -10.0, 10.0), 8, 5)
    z = sample_nominal_grid(_tilted_block(), plan)
    x, y = plan.points_xy.T
    over = x <= 20.0
    assert np.allclose(z[over], _plane(x[over], y[over]), atol=1e-9)
    assert np.isnan(z[~over]).all() and (~over).any()


def test_the_fitted_top_is_the_plane():
    plan = plan_probe_grid(ProbeRegion(-15.0, 15.0, -12.0, 12.0), 7, 6)
    fit = fit_part_top(_tilted_block(), plan, SurfaceFitParams(hole_policy="fill"))
    (u0, u1), (v0, v1) = fit.surface.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, 23), np.linspace(v0, v1, 19), indexing="ij")
    p = fit.surface.evaluate(uu.ravel(), vv.ravel())
    assert np.abs(p[:, 2] - _plane(p[:, 0], p[:, 1])).max() < 1e-8
    assert fit.residual_max_mm < 1e-8
