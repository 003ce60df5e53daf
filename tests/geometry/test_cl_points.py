"""CL points: every emitted segment within the chord tolerance, verified independently."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.geometry.cl_points import cl_points
from app.geometry.errors import GeometryError
from app.geometry.nurbs import NurbsCurve
from app.geometry.shapes import trace_curve


def brute_sagitta(curve: NurbsCurve, u: np.ndarray, samples: int = 400) -> np.ndarray:
    """Independent check: distance of 400 curve samples per segment to the segment."""
    out = []
    for a, b in zip(u[:-1], u[1:]):
        p = curve.evaluate(np.linspace(a, b, samples))
        d = p[-1] - p[0]
        t = np.clip((p - p[0]) @ d / (d @ d), 0, 1)
        out.append(np.linalg.norm(p - (p[0] + t[:, None] * d), axis=1).max())
    return np.array(out)


def test_arc_needs_near_minimal_points() -> None:
    r, chord = 40.0, 0.001
    c = trace_curve({"type": "arc", "center": [0, 0], "radius": r, "start_deg": 0, "end_deg": 60})
    cl = cl_points(c, chord)
    optimal = int(np.ceil(c.length / np.sqrt(8 * chord * r)))  # a circle's minimum for sagitta <= chord
    assert len(cl.u) - 1 <= optimal + 1
    assert brute_sagitta(c, cl.u).max() <= chord * (1 + 1e-6)
    assert np.allclose(np.linalg.norm(cl.points, axis=1), r, atol=1e-12)


def test_polyline_corners_are_kept_and_straight_lines_need_two_points() -> None:
    pts = [[0, 0], [5, 0], [5, 5], [9, 1]]
    c = trace_curve({"type": "polyline", "points": pts})
    cl = cl_points(c, 0.01)
    assert np.allclose(cl.points, pts)
    assert cl.max_sagitta_mm < 1e-12


@given(seed=st.integers(0, 10_000), chord=st.sampled_from([0.001, 0.005, 0.05]))
@settings(max_examples=15, deadline=None)
def test_chord_height_property_on_every_segment(seed: int, chord: float) -> None:
    rng = np.random.default_rng(seed)
    n, p = 7, 3
    knots = np.concatenate([np.zeros(p + 1), np.sort(rng.uniform(0, 1, n - p - 1)), np.ones(p + 1)])
    pts = np.column_stack([np.linspace(0, 30, n), rng.uniform(-8, 8, n), rng.uniform(-2, 2, n)])
    c = NurbsCurve(p, knots, pts, rng.uniform(0.5, 2, n))
    cl = cl_points(c, chord)
    assert cl.max_sagitta_mm <= chord
    assert brute_sagitta(c, cl.u, 200).max() <= chord * (1 + 1e-6)
    assert cl.u[0] == c.domain[0] and cl.u[-1] == c.domain[1]


def test_bad_tolerance() -> None:
    with pytest.raises(GeometryError) as info:
        cl_points(trace_curve({"type": "line", "start": [0, 0], "end": [1, 0]}), 0.0)
    assert info.value.field == "chord_mm"
