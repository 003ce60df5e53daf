"""NurbsSurface against geomdl and analytic surfaces."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.geometry.errors import GeometryError, KnotVectorError, WeightError
from app.geometry.nurbs_surface import NurbsSurface


def random_surface(seed: int, nu: int = 6, nv: int = 5, pu: int = 3, pv: int = 2) -> NurbsSurface:
    rng = np.random.default_rng(seed)
    uu, vv = np.meshgrid(np.linspace(0, 40, nu), np.linspace(0, 60, nv), indexing="ij")
    net = np.stack([uu, vv, rng.normal(0, 2, (nu, nv))], axis=-1)
    return NurbsSurface(pu, pv, None, None, net, rng.uniform(0.5, 2.0, (nu, nv)))


def test_evaluation_and_partials_equal_geomdl() -> None:
    s = random_surface(1)
    g = s.to_geomdl()
    rng = np.random.default_rng(2)
    u, v = rng.uniform(0, 1, 9), rng.uniform(0, 1, 9)
    assert np.abs(np.array(g.evaluate_list(list(zip(u.tolist(), v.tolist())))) - s.evaluate(u, v)).max() < 1e-12
    d = s.derivatives(u, v, 2)
    for k, (a, b) in enumerate(zip(u, v)):
        ref = g.derivatives(float(a), float(b), 2)
        for i in range(3):
            for j in range(3 - i):
                assert np.allclose(d[i][j][k], ref[i][j], rtol=1e-10, atol=1e-9)


def test_plane_normal_and_cylinder_exactness() -> None:
    # tilted bilinear plane z = 0.5 x: normal (-0.5, 0, 1)/|.|
    net = np.array([[[0, 0, 0], [0, 10, 0]], [[10, 0, 5], [10, 10, 5]]], float)
    plane = NurbsSurface(1, 1, None, None, net)
    n = plane.normal([0.2, 0.7], [0.3, 0.9])
    assert np.allclose(n, np.array([-0.5, 0, 1]) / np.sqrt(1.25), atol=1e-14)
    # quarter cylinder of radius 7 (exact rational quadratic in u, linear in v)
    w = np.sqrt(0.5)
    ring = np.array([[7, 0], [7, 7], [0, 7]], float)
    net = np.stack([np.column_stack([ring, np.full(3, z)]) for z in (0.0, 20.0)], axis=1)
    cyl = NurbsSurface(2, 1, None, None, net, np.array([[1, 1], [w, w], [1, 1]]))
    u, v = np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 5), indexing="ij")
    p = cyl.evaluate(u.ravel(), v.ravel())
    assert np.abs(np.hypot(p[:, 0], p[:, 1]) - 7).max() < 1e-12
    nn = cyl.normal(u.ravel(), v.ravel())
    radial = p[:, :2] / np.hypot(p[:, 0], p[:, 1])[:, None]
    assert np.allclose(np.abs(np.einsum("ij,ij->i", nn[:, :2], radial)), 1.0, atol=1e-12)


@given(seed=st.integers(0, 1000), u=st.floats(0, 1), v=st.floats(0, 1))
@settings(max_examples=30, deadline=None)
def test_inversion_recovers_parameters(seed: int, u: float, v: float) -> None:
    s = random_surface(seed)
    inv = s.invert(s.evaluate(u, v))
    assert inv.distance[0] < 1e-9
    assert abs(inv.u[0] - u) < 1e-7 and abs(inv.v[0] - v) < 1e-7


def test_round_trips_and_mesh() -> None:
    s = random_surface(3)
    for other in (NurbsSurface.from_dict(s.to_dict()), NurbsSurface.from_geomdl(s.to_geomdl())):
        assert np.allclose(other.control_points, s.control_points, atol=1e-12)
        assert np.allclose(other.weights, s.weights)
        assert np.array_equal(other.knots_u, s.knots_u) and np.array_equal(other.knots_v, s.knots_v)
    mesh = s.to_mesh(9, 7)
    assert len(mesh.faces) == 2 * 8 * 6
    assert np.allclose(mesh.vertices[0], s.evaluate(0, 0)[0])


@pytest.mark.parametrize(
    "patch,error,field",
    [
        ({"knots_u": [0, 0, 0.5, 1, 1]}, KnotVectorError, "surface.knots_u"),
        ({"weights": [[1, 1], [1, -1]]}, WeightError, "surface.weights"),
        ({"control_points": [[0, 0, 0]]}, GeometryError, "surface.control_points"),
        ({"degree_v": 2}, GeometryError, "surface.control_points"),
    ],
)
def test_bad_surface_input(patch: dict, error: type, field: str) -> None:
    data = {"degree_u": 1, "degree_v": 1, "control_points": [[[0, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 1]]]}
    with pytest.raises(error) as info:
        NurbsSurface.from_dict({**data, **patch})
    assert info.value.field == field
