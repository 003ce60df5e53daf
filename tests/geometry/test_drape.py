"""Draping onto faceted meshes: analytic planes and spheres, exactness, steps, off-surface errors."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from app.geometry.drape import drape_polyline, snap_to_surface, top_surface_z
from app.geometry.errors import DegenerateGeometryError, OffSurfaceError
from tests.geometry.conftest import height_field_mesh, wavy

# embree finds the facet in float32: within ~1e-6 mm of an edge it may name the neighbour facet,
# whose plane is then extrapolated by that much -> height differences of ~1e-9 mm.
EXACT_MM = 1e-7


def assert_exact_on_mesh(mesh: trimesh.Trimesh, points: np.ndarray) -> None:
    """Every draped vertex and every point of every draped segment lies on the upper surface."""
    top = top_surface_z(mesh, points[:, :2])
    assert top.hit.all() and np.abs(top.z - points[:, 2]).max() < EXACT_MM
    for f in (0.25, 0.5, 0.75):
        inner = points[:-1] + f * (points[1:] - points[:-1])
        moving = np.linalg.norm(points[1:, :2] - points[:-1, :2], axis=1) > 0
        t = top_surface_z(mesh, inner[moving, :2])
        assert np.abs(t.z - inner[moving, 2]).max() < EXACT_MM


def test_plane_and_tilted_plane() -> None:
    for a, b, c in ((0, 0, 3.0), (0.3, -0.2, 10.0)):
        mesh = height_field_mesh(lambda x, y, a=a, b=b, c=c: a * x + b * y + c, 9, 13)
        xy = np.array([[1, 1], [30, 50], [35.5, 2.2], [2, 58]])
        d = drape_polyline(mesh, xy)
        assert np.abs(d.points[:, 2] - (a * d.points[:, 0] + b * d.points[:, 1] + c)).max() < 1e-12
        n = np.array([-a, -b, 1.0]) / np.sqrt(a * a + b * b + 1)
        assert np.allclose(d.normals, n, atol=1e-12)
        xy_len = np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()
        assert d.xy_length_mm == pytest.approx(xy_len)
        # on a plane the stretch of each top-view segment is sqrt(1 + slope along it ^ 2)
        seg = np.diff(xy, axis=0)
        slope = (seg @ [a, b]) / np.linalg.norm(seg, axis=1)
        assert d.length_mm == pytest.approx((np.linalg.norm(seg, axis=1) * np.sqrt(1 + slope**2)).sum(), rel=1e-12)
        assert d.slope_stretch == pytest.approx(d.length_mm / xy_len)
        assert d.s_mm[-1] == pytest.approx(d.length_mm)


def test_sphere_against_analytic_height() -> None:
    r = 50.0
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=r)
    xy = np.column_stack([np.linspace(-20, 25, 7), np.linspace(15, -10, 7)])
    d = drape_polyline(sphere, xy)
    analytic = np.sqrt(r**2 - d.points[:, 0] ** 2 - d.points[:, 1] ** 2)
    # faceting error of a level-5 icosphere: the chord sagitta of ~2 mm edges on r = 50
    assert np.abs(d.points[:, 2] - analytic).max() < 0.02
    assert (d.points[:, 2] <= analytic + 1e-9).all()  # inscribed facets lie below the sphere
    assert_exact_on_mesh(sphere, d.points)
    radial = d.points / np.linalg.norm(d.points, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", radial, d.normals).min() > 0.99


def test_grid_line_and_diagonal_inserting_every_crossing(wavy_mesh: trimesh.Trimesh) -> None:
    d = drape_polyline(wavy_mesh, [[0, 10], [40, 10]])  # exactly along a row of mesh vertices
    assert np.abs(d.points[:, 2] - wavy(d.points[:, 0], d.points[:, 1])).max() < 1e-12
    assert len(d.points) == 41
    d = drape_polyline(wavy_mesh, [[0.5, 0.5], [39.5, 59.5]])
    assert_exact_on_mesh(wavy_mesh, d.points)


def test_step_keeps_both_heights() -> None:
    low = trimesh.creation.box(extents=[20, 20, 2])
    high = trimesh.creation.box(extents=[10, 20, 2])
    high.apply_translation([5, 0, 2])
    mesh = trimesh.util.concatenate([low, high])
    d = drape_polyline(mesh, [[-8, 0], [8, 0]])
    assert np.allclose(d.points[[0, -1], 2], [1, 3])
    at_step = np.isclose(d.points[:, 0], 0.0)
    assert sorted(d.points[at_step, 2].tolist()) == pytest.approx([1.0, 3.0])
    assert d.length_mm == pytest.approx(16 + 2)


@given(
    pts=st.lists(st.tuples(st.floats(0.01, 39.99), st.floats(0.01, 59.99)), min_size=2, max_size=6),
)
@settings(max_examples=25, deadline=None)
def test_property_draped_path_lies_on_the_mesh(wavy_mesh: trimesh.Trimesh, pts: list) -> None:
    xy = np.array(pts)
    if np.linalg.norm(np.diff(xy, axis=0), axis=1).sum() < 1e-3:
        return
    d = drape_polyline(wavy_mesh, xy)
    assert_exact_on_mesh(wavy_mesh, d.points)
    assert d.slope_stretch >= 1.0 - 1e-12
    # every input vertex is a vertex of the draped path; the top view is unchanged
    assert max(np.linalg.norm(d.points[:, :2] - p, axis=1).min() for p in xy) < 1e-12
    assert d.xy_length_mm == pytest.approx(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())


def test_off_surface_and_degenerate(wavy_mesh: trimesh.Trimesh) -> None:
    with pytest.raises(OffSurfaceError) as info:
        drape_polyline(wavy_mesh, [[5, 5], [50, 5]])
    assert "x=40.0, y=5.0" in info.value.message and info.value.field == "geometry"
    assert info.value.value[0] > 40
    with pytest.raises(OffSurfaceError) as info:
        drape_polyline(wavy_mesh, [[5, 5], [10, 5], [10, -3], [5, -3]])
    assert info.value.value == [10.0, -1.5]  # a point of the first stretch off the part
    assert "leaves the part's surface at x=10.0, y=0.0" in info.value.message
    with pytest.raises(DegenerateGeometryError):
        drape_polyline(wavy_mesh, [[5, 5], [5, 5]])
    z = top_surface_z(wavy_mesh, [[1, 1], [-1, 1]])
    assert z.hit.tolist() == [True, False] and np.isnan(z.z[1])


def test_top_surface_and_snap(wavy_mesh: trimesh.Trimesh) -> None:
    xy = np.array([[0, 0], [20, 30], [40, 60], [13.0, 7.0]])  # grid vertices are exact
    top = top_surface_z(wavy_mesh, xy)
    assert np.abs(top.z - wavy(xy[:, 0], xy[:, 1])).max() < 1e-12
    pts = np.column_stack([xy, top.z + [0.01, -0.01, 0.0, 0.02]])
    snapped = snap_to_surface(wavy_mesh, pts, 0.05)
    assert snapped.distance.max() <= 0.02 + 1e-12 and (snapped.normals[:, 2] > 0).all()
    with pytest.raises(OffSurfaceError) as info:
        snap_to_surface(wavy_mesh, pts + [0, 0, 1.0], 0.05)
    assert info.value.value == [0.0, 0.0, round(float(pts[0, 2] + 1), 6)]
