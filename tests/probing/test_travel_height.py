"""The highest point of a mesh above many segments at once, against dense vertical rays."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.probing.travel_height import segments_top_max
from app.reference.boards import dome_part


def _sampled_top(mesh: trimesh.Trimesh, a: np.ndarray, b: np.ndarray, n: int = 801) -> float:
    """The highest ray hit over ``n`` points of the segment a-b (-inf when none hits): the
    section is linear between its vertices, so the samples can only be lower than the truth."""
    xy = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    origins = np.column_stack([xy, np.full(n, mesh.bounds[1][2] + 1.0)])
    loc, _, _ = mesh.ray.intersects_location(origins, np.tile([0.0, 0.0, -1.0], (n, 1)))
    return float(loc[:, 2].max()) if len(loc) else -np.inf


@pytest.mark.parametrize("name", ["dome", "sphere", "annulus", "box"])
def test_every_segment_at_once_matches_dense_rays(name):
    mesh = {"dome": lambda: dome_part().mesh(grid_mm=2.0), "sphere": lambda: trimesh.creation.icosphere(3, 15.0),
            "annulus": lambda: trimesh.creation.annulus(5.0, 12.0, 8.0),
            "box": lambda: trimesh.creation.box((20.0, 30.0, 10.0))}[name]()
    rng = np.random.default_rng(3)
    lo, hi = mesh.bounds[0][:2] - 2.0, mesh.bounds[1][:2] + 2.0
    a, b = rng.uniform(lo, hi, (40, 2)), rng.uniform(lo, hi, (40, 2))
    b[:5] = a[:5] + rng.normal(0.0, 0.2, (5, 2))  # short hops, as between probe stations
    a[5:10, 0] = b[5:10, 0] = np.round(a[5:10, 0])  # along a column of the dome's vertices
    tops = segments_top_max(mesh, a, b)
    slope = 4.0  # mm per mm: steeper than any face these segments leave the part over
    for k in range(len(a)):
        sampled = _sampled_top(mesh, a[k], b[k])
        if np.isinf(sampled):  # no face above the segment (an off-part hop): none found either
            assert tops[k] == -np.inf or tops[k] <= mesh.bounds[1][2]
            continue
        spacing = float(np.linalg.norm(b[k] - a[k])) / 800
        assert sampled - 1e-9 <= tops[k] <= sampled + slope * spacing + 1e-9, (k, a[k], b[k])


def test_a_hop_along_a_row_of_vertices_sees_the_part_and_a_point_sees_its_top():
    mesh = dome_part().mesh(grid_mm=0.5)
    a, b = np.array([[56.0, 30.5], [70.0, 50.0]]), np.array([[56.0, 27.25], [70.0, 50.0]])
    tops = segments_top_max(mesh, a, b)
    assert tops[0] == pytest.approx(_sampled_top(mesh, a[0], b[0], 2001), abs=1e-3) and tops[0] > 10.0
    assert tops[1] == pytest.approx(float(dome_part().height(b[1:])[0]), abs=0.05)  # the dome's top there


def test_off_the_part_nothing_is_above():
    mesh = trimesh.creation.box((20.0, 30.0, 10.0))
    tops = segments_top_max(mesh, np.array([[30.0, 30.0], [30.0, 30.0]]), np.array([[40.0, 45.0], [30.0, 30.0]]))
    assert tops.tolist() == [-np.inf, -np.inf]
    across = segments_top_max(mesh, np.array([[-30.0, 0.0]]), np.array([[30.0, 0.0]]))
    assert across[0] == pytest.approx(5.0)  # the box's top, over its walls
