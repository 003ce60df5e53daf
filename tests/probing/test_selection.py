"""Probe selection: the seed's chord-height rule, uniform baseline, deviation planner."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.geometry.traces import as_trace_polyline
from app.platform.problems import http_status
from app.probing.selection import (
    PlanError,
    PlanParams,
    chord_height_select,
    chord_heights,
    deviation_spacing,
    deviation_stations,
    plan_probes,
)


def wavy_curve(a1, a2, w1, w2, n=400):
    t = np.linspace(0.0, 30.0, n)
    return np.column_stack([t, a1 * np.sin(w1 * t), 5 + a2 * np.cos(w2 * t)])


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 3.0), st.floats(0.0, 2.0), st.floats(0.05, 1.0), st.floats(0.05, 1.0),
       st.sampled_from([0.001, 0.01, 0.1]))
def test_chord_height_property_and_maximality(a1, a2, w1, w2, e):
    pts = wavy_curve(a1, a2, w1, w2)
    idx = chord_height_select(pts, e)
    assert idx[0] == 0 and idx[-1] == len(pts) - 1 and np.all(np.diff(idx) > 0)
    for a, b in zip(idx[:-1], idx[1:]):
        assert chord_heights(pts, a, b) <= e  # every CL point within e of its chord
    for a, b in zip(idx[:-2], idx[1:-1]):
        # the rule stopped because one more CL point would break the tolerance
        assert chord_heights(pts, a, b + 1) > e


def test_straight_line_needs_only_its_ends():
    pts = np.column_stack([np.linspace(0, 10, 50), np.zeros(50), np.zeros(50)])
    assert chord_height_select(pts, 1e-6).tolist() == [0, 49]


def test_circle_spacing_matches_sagitta():
    r, e = 20.0, 0.01
    ang = np.linspace(0, np.pi, 20001)
    pts = np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros_like(ang)])
    idx = chord_height_select(pts, e)
    half = np.arccos(1 - e / r)  # chord half-angle whose sagitta is e
    steps = np.diff(ang[idx])[:-1]
    assert np.allclose(steps, 2 * half, atol=2 * (ang[1] - ang[0]))


def test_uniform_and_eq1():
    path = as_trace_polyline(wavy_curve(1.0, 0.5, 0.3, 0.2))
    plan = plan_probes(path, "uniform", PlanParams(count=9))
    assert plan.count == 9
    assert np.allclose(np.diff(plan.s_mm), path.length_mm / 8)
    assert np.allclose(plan.points, path.at(plan.s_mm))
    eq1 = plan_probes(path, "uniform", PlanParams(capability_k=0.5, confidence=0.95))
    assert eq1.count == 13 and eq1.point_count.count == 13


def test_deviation_stations_and_spacing():
    s = deviation_stations(30.0, 8, 0.7)
    assert s[0] == 0 and s[-1] == 30.0 and len(s) == 8
    d = np.diff(s)
    assert np.allclose(d[1:-1], d[1]) and np.allclose(d[[0, -1]], 0.7 * d[1])
    p = PlanParams(deviation_amplitude_mm=0.2, deviation_wavelength_mm=20.0,
                   target_error_mm=0.005, probe_sigma_mm=0.001)
    h = deviation_spacing(p)
    # the bound it is built on holds with equality
    assert 5 / 384 * h ** 4 * 0.2 * (2 * np.pi / 20.0) ** 4 == pytest.approx(0.003)
    path = as_trace_polyline(wavy_curve(1.0, 0.5, 0.3, 0.2))
    plan = plan_probes(path, "deviation", p)
    assert plan.count == max(4, int(np.ceil(path.length_mm / h)) + 1)
    assert plan.spacing_mm == pytest.approx(h)


def test_adaptive_plan_uses_cl_points():
    path = as_trace_polyline(wavy_curve(2.0, 1.0, 0.4, 0.3, n=3000))
    plan = plan_probes(path, "adaptive", PlanParams(chord_error_mm=0.01, cl_tolerance_mm=0.001))
    cl = plan.cl_points
    # CL points honour their own tolerance against the dense nominal
    assert len(cl) < len(path.points)
    for a, b in zip(plan.points[:-1], plan.points[1:]):
        ia = int(np.flatnonzero((cl == a).all(axis=1))[0])
        ib = int(np.flatnonzero((cl == b).all(axis=1))[0])
        assert chord_heights(cl, ia, ib) <= 0.01
    assert np.all(np.diff(plan.s_mm) > 0)


def test_bad_parameters():
    path = as_trace_polyline(wavy_curve(1, 1, 0.1, 0.1))
    with pytest.raises(PlanError):
        plan_probes(path, "random")
    with pytest.raises(PlanError):
        plan_probes(path, "uniform", PlanParams())
    with pytest.raises(PlanError):
        PlanParams(chord_error_mm=-1)
    with pytest.raises(PlanError):
        PlanParams(count=1)
    with pytest.raises(PlanError):
        PlanParams(capability_k=0.5)
    with pytest.raises(PlanError):
        deviation_spacing(PlanParams(target_error_mm=0.002, probe_sigma_mm=0.001))
    with pytest.raises(Exception) as info:
        plan_probes(np.zeros((5, 3)), "uniform", PlanParams(count=4))
    assert http_status(info.value)[0] == 422
