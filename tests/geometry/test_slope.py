"""Slope policy for traces on a sphere: the largest slope, the warning and the refusal."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from app.geometry.slope import SlopePolicy, SteepTraceError, check_slope, height_error_mm, surface_slopes_deg
from app.geometry.tolerance import Tolerance
from app.geometry.traces import build_nominal_trace

R = 20.0


@pytest.fixture(scope="module")
def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=5, radius=R)


def test_slope_of_analytic_normals():
    angles = np.radians([0.0, 30.0, 60.0, 85.0])
    normals = np.column_stack([np.sin(angles), np.zeros(4), np.cos(angles)])
    assert surface_slopes_deg(normals) == pytest.approx([0.0, 30.0, 60.0, 85.0], abs=1e-9)
    assert height_error_mm(45.0, 0.01) == pytest.approx(0.01)
    assert height_error_mm(60.0, 0.01) == pytest.approx(0.01 * math.sqrt(3))


@pytest.mark.parametrize(("x_end", "outcome"), [(5.0, "ok"), (14.0, "warn"), (19.0, "refuse")])
def test_sphere_trace_slope_warn_and_refuse(sphere, x_end, outcome):
    nominal = build_nominal_trace(sphere, {"type": "line", "start": [0.0, 0.0], "end": [x_end, 0.0]}, "xy",
                                  Tolerance())
    truth = math.degrees(math.asin(x_end / R))        # the sphere's slope at the trace's end
    policy = SlopePolicy(warn_deg=30.0, max_deg=60.0)
    if outcome == "refuse":
        with pytest.raises(SteepTraceError) as err:
            check_slope(nominal.points, nominal.normals, policy)
        assert "five_axis" in err.value.message and err.value.field == "geometry"
        assert err.value.value == pytest.approx(truth, abs=2.0)   # facets of a 20 mm sphere
        relaxed = check_slope(nominal.points, nominal.normals, SlopePolicy(warn_deg=30.0, max_deg=80.0))
        assert relaxed.warnings and relaxed.max_slope_deg == pytest.approx(truth, abs=2.0)
        return
    report = check_slope(nominal.points, nominal.normals, policy)
    assert report.max_slope_deg == pytest.approx(truth, abs=2.0)
    assert np.allclose(report.point[:2], [x_end, 0.0], atol=0.5)          # the steepest point is the far end
    assert bool(report.warnings) == (outcome == "warn")
    assert report.height_error_mm == pytest.approx(0.01 * math.tan(math.radians(report.max_slope_deg)))
