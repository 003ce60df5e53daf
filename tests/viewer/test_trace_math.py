"""Feet of measured points on a trace and contour rings as segments."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from app.viewer.trace_math import project_onto_polyline, rings_to_segments


def test_points_above_a_sloped_line_project_straight_down():
    line = np.array([[0, 0, 0], [10, 0, 10], [10, 10, 10]], float)
    pts = np.array([[5, 0, 7.0], [10, 4, 9.0], [-3, 0, 1.0]])
    proj = project_onto_polyline(pts, line)
    # first leg is 10*sqrt(2) long (3-D arc length), the foot of (5,0) is its midpoint
    assert np.allclose(proj.s_mm, [5 * np.sqrt(2), 10 * np.sqrt(2) + 4, 0.0])
    assert np.allclose(proj.nominal, [[5, 0, 5], [10, 4, 10], [0, 0, 0]])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0, 1), min_size=1, max_size=20), st.floats(-1, 1))
def test_points_on_a_circle_arc_recover_their_arc_length(fractions, dz):
    """Points over a finely sampled arc: s is the polyline length to the point (radius r)."""
    r, n = 20.0, 2001
    theta = np.linspace(0, np.pi / 2, n)
    line = np.column_stack([r * np.cos(theta), r * np.sin(theta), np.zeros(n)])
    t = np.asarray(fractions) * np.pi / 2
    pts = np.column_stack([r * np.cos(t), r * np.sin(t), np.full(len(t), dz)])
    proj = project_onto_polyline(pts, line)
    assert np.allclose(proj.s_mm, r * t, atol=1e-3)
    assert np.allclose(pts[:, 2] - proj.nominal[:, 2], dz)


def test_rings_close_and_sit_at_their_height():
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    closed_triangle = [[0, 0], [2, 0], [0, 2], [0, 0]]
    segs = rings_to_segments([square, closed_triangle, [[5, 5]]], z=1.5)
    assert segs.shape == (4 + 3, 2, 3)
    assert np.all(segs[..., 2] == 1.5)
    assert np.allclose(segs[3], [[0, 1, 1.5], [0, 0, 1.5]])  # the square's closing edge
    assert np.isclose(np.linalg.norm(segs[:4, 1] - segs[:4, 0], axis=1).sum(), 4.0)
    assert rings_to_segments([], 0.0).shape == (0, 2, 3)
