"""NurbsCurve against analytic truth and geomdl as the oracle."""

from __future__ import annotations

import numpy as np
import pytest
from geomdl import NURBS
from hypothesis import given, settings
from hypothesis import strategies as st

from app.geometry.errors import DegenerateGeometryError, GeometryError, KnotVectorError, WeightError
from app.geometry.nurbs import NurbsCurve
from app.platform.problems import http_status

S = np.sqrt(0.5)


def quarter_circle(r: float = 1.0) -> NurbsCurve:
    return NurbsCurve(2, np.array([0, 0, 0, 1, 1, 1.0]), r * np.array([[1, 0], [1, 1], [0, 1.0]]), np.array([1, S, 1]))


def random_curve(seed: int, n: int = 7, degree: int = 3, dim: int = 3) -> NurbsCurve:
    rng = np.random.default_rng(seed)
    inner = np.sort(rng.uniform(0, 1, n - degree - 1))
    knots = np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])
    pts = np.cumsum(rng.uniform(0.5, 3, (n, dim)), axis=0)
    return NurbsCurve(degree, knots, pts, rng.uniform(0.5, 2.0, n))


def test_circle_points_curvature_and_length() -> None:
    c = quarter_circle(40.0)
    u = np.linspace(0, 1, 201)
    assert np.abs(np.linalg.norm(c.evaluate(u), axis=1) - 40.0).max() < 1e-12
    assert np.allclose(c.curvature(u), 1 / 40.0, rtol=1e-12)
    assert c.length == pytest.approx(40.0 * np.pi / 2, rel=1e-12)
    assert c.arc_length(0.0, 0.5) == pytest.approx(20.0 * np.pi / 2, rel=1e-12)  # symmetric weights


def test_param_at_length_round_trip() -> None:
    c = random_curve(3)
    s = np.linspace(0, c.length, 37)
    u = c.param_at_length(s)
    back = np.array([c.arc_length(c.domain[0], ui) for ui in u])
    assert np.abs(back - s).max() < 1e-9 * c.length


@pytest.mark.parametrize("seed,dim,degree", [(0, 3, 3), (1, 2, 2), (2, 3, 4), (5, 2, 1)])
def test_evaluation_and_derivatives_equal_geomdl(seed: int, dim: int, degree: int) -> None:
    c = random_curve(seed, n=8, degree=degree, dim=dim)
    g = c.to_geomdl()
    u = np.linspace(0, 1, 13)
    assert np.abs(np.array(g.evaluate_list(u.tolist())) - c.evaluate(u)).max() < 1e-12
    d = c.derivatives(u, 2)
    ref = np.array([g.derivatives(float(x), 2) for x in u])  # (k, 3, dim)
    assert np.abs(ref.transpose(1, 0, 2) - d).max() < 1e-9 * np.abs(ref).max()


def test_curvature_of_a_helix() -> None:
    # helix (a cos t, a sin t, b t) has curvature a / (a^2 + b^2): interpolate it densely
    from app.geometry.fitting import interpolate_curve

    t = np.linspace(0, 4 * np.pi, 400)
    c = interpolate_curve(np.column_stack([3 * np.cos(t), 3 * np.sin(t), 0.5 * t]))
    u = np.linspace(0.1, 0.9, 9)
    assert np.allclose(c.curvature(u), 3 / (9 + 0.25), rtol=1e-4)


def test_geomdl_and_dict_round_trips() -> None:
    c = random_curve(4)
    for other in (NurbsCurve.from_geomdl(c.to_geomdl()), NurbsCurve.from_dict(c.to_dict())):
        assert other.degree == c.degree
        assert np.array_equal(other.knots, c.knots)
        assert np.allclose(other.control_points, c.control_points, atol=1e-12)
        assert np.allclose(other.weights, c.weights, atol=1e-15)
    g = NURBS.Curve()
    g.degree = 1
    g.ctrlpts = [[0.0, 0.0], [2.0, 0.0]]
    g.knotvector = [0, 0, 1, 1]
    assert NurbsCurve.from_geomdl(g).length == pytest.approx(2.0)


def test_from_dict_defaults_clamped_uniform() -> None:
    c = NurbsCurve.from_dict({"degree": 2, "control_points": [[0, 0], [1, 1], [2, 0], [3, 1]]})
    assert c.knots.tolist() == [0, 0, 0, 0.5, 1, 1, 1]
    assert np.allclose(c.evaluate([0, 1]), [[0, 0], [3, 1]])


@given(seed=st.integers(0, 10_000), u=st.floats(0.0, 1.0))
@settings(max_examples=40, deadline=None)
def test_inversion_recovers_parameter(seed: int, u: float) -> None:
    # monotone control points in x -> the curve is injective, the parameter is unique
    c = random_curve(seed)
    inv = c.invert(c.evaluate([u]))
    assert inv.distance[0] < 1e-9
    assert abs(inv.u[0] - u) < 1e-7


def test_inversion_of_off_curve_points() -> None:
    c = quarter_circle(10.0)
    angles = np.linspace(0.1, 1.4, 7)
    pts = np.column_stack([np.cos(angles), np.sin(angles)]) * 13.0
    inv = c.invert(pts)
    assert np.allclose(inv.distance, 3.0, atol=1e-9)
    assert np.allclose(np.arctan2(inv.closest[:, 1], inv.closest[:, 0]), angles, atol=1e-9)


@pytest.mark.parametrize(
    "data,error,field,value",
    [
        ({"degree": 3, "control_points": [[0, 0], [1, 1], [2, 0], [3, 1]], "knots": [0, 0, 1, 1]},
         KnotVectorError, "curve.knots", 4),
        ({"degree": 1, "control_points": [[0, 0], [1, 1]], "knots": [0, 1, 0.5, 1]}, KnotVectorError,
         "curve.knots", [1.0, 0.5]),
        ({"degree": 1, "control_points": [[0, 0], [1, 1]], "weights": [1, 0]}, WeightError, "curve.weights", 0.0),
        ({"degree": 1, "control_points": [[0, 0], [1, 1]], "weights": [1]}, WeightError, "curve.weights", [1]),
        ({"degree": 3, "control_points": [[0, 0], [1, 1]]}, DegenerateGeometryError, "curve.control_points", 2),
        ({"degree": 1, "control_points": [[0, 0], [1, float("nan")]]}, DegenerateGeometryError,
         "curve.control_points[1]", [1.0, "nan"]),
        ({"degree": 0, "control_points": [[0, 0], [1, 1]]}, GeometryError, "curve.degree", 0),
        ({"control_points": [[0, 0], [1, 1]]}, GeometryError, "curve.degree", None),
    ],
)
def test_bad_input_names_field_and_value(data: dict, error: type, field: str, value: object) -> None:
    with pytest.raises(error) as info:
        NurbsCurve.from_dict(data)
    assert info.value.field == field
    assert info.value.value == value
    assert http_status(info.value)[0] == 422


def test_parameters_outside_domain_are_rejected() -> None:
    with pytest.raises(GeometryError):
        quarter_circle().evaluate([1.5])
    with pytest.raises(GeometryError):
        quarter_circle().evaluate([float("nan")])
