"""Kriging reconstruction of a trace draped on a faceted mesh: a smooth real surface, a
span that covers the trace, and a compensated program that holds the standoff."""

import numpy as np
import pytest

from app.compensation.standoff import CompensationParams, compensate_trace
from app.geometry.drape import drape_polyline
from app.geometry.traces import as_trace_polyline
from app.probing.deviation_prior import path_gradient, raw_path_gradient
from app.probing.selection import PlanParams, plan_probes
from app.reconstruction.reconstruct import ReconstructParams, reconstruct
from app.reference.s1 import as_made, s1_mesh, s1_traces, trace_xy

PROCESS = dict(deviation_amplitude_mm=0.15, deviation_wavelength_mm=15.0)


@pytest.fixture(scope="module")
def draped():
    """S1 trace 6 (an arc) draped on the 0.5 mm-grid mesh, as the service stores it."""
    d = drape_polyline(s1_mesh(grid_mm=0.5), trace_xy(s1_traces()[5].geometry, 0.5))
    return as_trace_polyline(d)


def test_smoothed_slope_is_continuous_where_the_faceted_one_jumps(draped):
    s = np.linspace(0.0, draped.length_mm, 20001)  # 1.7 um apart
    raw_kinks = np.abs(np.diff(raw_path_gradient(draped, s), 2, axis=0)).max()
    smooth = path_gradient(draped, s)
    assert raw_kinks > 1e-3  # steps where the trace changes face (measured 3.3e-3)
    assert np.abs(np.diff(smooth, 2, axis=0)).max() < 1e-5  # measured 4.7e-7
    # and it is still the surface's slope, on average over a few tenths of a mm
    assert np.abs(smooth - raw_path_gradient(draped, s)).mean() < 0.01


def test_kriging_span_reaches_a_quarter_wavelength_past_the_probes(draped):
    pts = draped.at(np.linspace(3.0, draped.length_mm - 1.0, 8))
    krig = reconstruct(draped, pts, "kriging", 0.001, ReconstructParams(prior=PlanParams(**PROCESS).prior()))
    assert krig.span_mm == pytest.approx((0.0, draped.length_mm))  # 3 mm < 15 / 4, 1 mm too
    inner = reconstruct(draped, draped.at(np.linspace(5.0, 20.0, 8)), "kriging", 0.001,
                        ReconstructParams(prior=PlanParams(**PROCESS).prior()))
    assert inner.span_mm == pytest.approx((5.0 - 3.75, 20.0 + 3.75), abs=1e-6)
    interp = reconstruct(draped, pts, "interpolate", 0.001)
    assert interp.span_mm == pytest.approx((3.0, draped.length_mm - 1.0), abs=1e-6)


def test_kriging_reconstruction_of_a_draped_trace_compensates_and_holds_the_standoff(draped):
    part = as_made(7)
    plan = plan_probes(draped, "kriging", PlanParams(**PROCESS))
    pts = plan.points.copy()
    pts[:, 2] = part.true_height(pts[:, :2]) + np.random.default_rng(1).normal(0, 0.001, len(pts))
    rec = reconstruct(draped, pts, "kriging", 0.001, ReconstructParams(prior=PlanParams(**PROCESS).prior()))
    out = compensate_trace(rec, CompensationParams(standoff_mm=0.1))
    # the tip sits 0.1 mm above the TRUE part (facets of a 0.5 mm mesh add their own sag)
    s = np.linspace(0.0, draped.length_mm, 400)
    tip = rec.height_at_s(s) + 0.1
    assert np.abs(tip - part.true_height(draped.at(s)[:, :2]) - 0.1).max() < 0.02
    assert out.program.count("\n") > 10
