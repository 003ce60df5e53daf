"""Slicing a part into layers: the mesh prepared once, then a layer-thickness planner of
:mod:`app.slicing.adaptive` building :class:`~app.slicing.layers.Layer` s."""

from __future__ import annotations

import trimesh

from app.slicing import adaptive
from app.slicing.errors import SlicingError
from app.slicing.layers import Sampler, SliceParams, SliceResult
from app.slicing.mesh_prep import PreparedMesh, prepare_mesh


def slice_mesh(mesh: trimesh.Trimesh | PreparedMesh, params: SliceParams) -> SliceResult:
    """Slice ``mesh`` (a trimesh or an already prepared mesh) into layers.

    Raises :class:`SlicingError` for bad parameters, an unusable mesh, a layer with no
    area, or more than ``params.max_layers`` layers.
    """
    params.validate()
    prepared = mesh if isinstance(mesh, PreparedMesh) else prepare_mesh(mesh, params.repair, params.max_hole_mm)
    height = prepared.z_max - prepared.z_min
    if not height > 2 * params.z_tol:
        raise SlicingError(f"part height {height:.6g} mm is too small to slice",
                           field="mesh", value=float(height))
    sampler = Sampler(prepared, params.z_tol)
    planner = {"uniform": adaptive.uniform_layers, "area": adaptive.area_layers,
               "cavity": adaptive.area_layers, "cusp": adaptive.cusp_layers}[params.mode]
    plan = planner(sampler, params)
    return SliceResult(layers=tuple(plan.layers), params=params, z_min=prepared.z_min,
                       z_max=prepared.z_max, bounds=prepared.bounds, volume=prepared.volume,
                       repairs=prepared.repairs, notes=tuple(plan.notes))
