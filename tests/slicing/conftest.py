"""Mesh builders for the slicing tests (exact solids via manifold3d booleans)."""

from __future__ import annotations

import manifold3d
import numpy as np
import trimesh


def to_trimesh(solid: manifold3d.Manifold) -> trimesh.Trimesh:
    m = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts),
                           process=True)


def cavity_block(n_cavities: int, band=(2.0, 4.0), size=(40.0, 10.0, 6.0),
                 radius=1.2) -> trimesh.Trimesh:
    """A block with ``n_cavities`` closed cylindrical cavities spanning z in ``band``."""
    block = manifold3d.Manifold.cube(size)
    xs = np.linspace(0, size[0], n_cavities + 2)[1:-1]
    holes = [manifold3d.Manifold.cylinder(band[1] - band[0], radius, radius, 48)
             .translate((float(x), size[1] / 2, band[0])) for x in xs]
    return to_trimesh(block - manifold3d.Manifold.batch_boolean(holes, manifold3d.OpType.Add))


def stepped_block(step_z=3.0) -> trimesh.Trimesh:
    """A 20x20 base (z 0..step_z) with a 10x10 tower on top (z step_z..6)."""
    base = manifold3d.Manifold.cube((20.0, 20.0, step_z))
    tower = manifold3d.Manifold.cube((10.0, 10.0, 6.0 - step_z)).translate((5.0, 5.0, step_z))
    return to_trimesh(base + tower)


def channel_block(n_channels: int, size=(40.0, 10.0, 6.0), radius=1.4) -> trimesh.Trimesh:
    """A block with ``n_channels`` closed horizontal cylindrical channels (axis along y,
    centred at z = size_z / 2, 1 mm short of both y faces): curved cavity walls in z."""
    block = manifold3d.Manifold.cube(size)
    xs = np.linspace(0, size[0], n_channels + 2)[1:-1]
    length = size[1] - 2.0
    holes = [manifold3d.Manifold.cylinder(length, radius, radius, 64)
             .rotate((-90.0, 0.0, 0.0)).translate((float(x), 1.0, size[2] / 2))
             for x in xs]
    return to_trimesh(block - manifold3d.Manifold.batch_boolean(holes, manifold3d.OpType.Add))
