"""Vertical probing against a placed mesh, checked against the analytic sphere."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from hardware.mock import TruePlacement
from hardware.mock.surface import PlacedSurface, placement_matrix


def test_placement_matrix_rotates_then_translates():
    matrix = placement_matrix(TruePlacement(dx=1.0, dy=2.0, dz=3.0, rz_deg=90.0))
    point = matrix @ np.array([1.0, 0.0, 0.0, 1.0])
    assert np.allclose(point[:3], [1.0, 3.0, 3.0])


def test_probe_meets_sphere_top_bed_and_reports_inside():
    radius = 10.0
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    sphere.apply_translation((5.0, 0.0, 0.0))
    placement = TruePlacement(dx=0.5, dy=-0.3, dz=0.2, rz_deg=30.0)
    surface = PlacedSurface(sphere, placement, bed_z=-20.0)
    angle = math.radians(30.0)
    cx, cy, cz = 5.0 * math.cos(angle) + 0.5, 5.0 * math.sin(angle) - 0.3, 0.2
    # facets lie inside the sphere by at most the sagitta of the coarsest face
    sag = radius - np.linalg.norm(sphere.triangles_center - (5.0, 0.0, 0.0), axis=1).min()
    for dx, dy in [(0, 0), (3, 1), (-4, 2), (6, -5)]:
        x, y = cx + dx, cy + dy
        height = math.sqrt(radius**2 - dx**2 - dy**2)
        expected = cz + height
        vertical_sag = sag / (height / radius)  # radial gap seen along a vertical ray
        hit = surface.probe(x, y, 30.0, -30.0)
        assert not hit.started_inside
        assert expected - vertical_sag - 1e-9 <= hit.z <= expected + 1e-9
    assert surface.probe(cx + 20, cy, 30.0, -30.0).z == -20.0       # bed beside the part
    assert surface.probe(cx + 20, cy, 30.0, -10.0).z is None         # bed out of reach
    assert surface.probe(cx, cy, cz, -30.0).started_inside          # starts inside the part
