"""The compensation error model's slope term, checked on a sphere against a real lateral error."""

from __future__ import annotations

import numpy as np
import pytest

from app.compensation.standoff import CompensationParams, compensate_trace
from app.geometry.traces import TracePolyline
from tests.compensation.test_standoff import AnalyticReconstruction

R = 20.0


def sphere_z(xy: np.ndarray, dx: float = 0.0) -> np.ndarray:
    return np.sqrt(R * R - (xy[:, 0] - dx) ** 2 - xy[:, 1] ** 2)


def test_slope_term_predicts_the_standoff_error_of_a_lateral_shift():
    x = np.linspace(0.0, 15.0, 1501)                      # up to asin(15 / 20) = 48.6 deg
    pts = np.column_stack([x, np.zeros_like(x), sphere_z(np.column_stack([x, 0 * x]))])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    path = TracePolyline(points=pts, s=s, normals=pts / R)
    rec = AnalyticReconstruction(path, lambda xy: sphere_z(xy), np.linspace(0.0, s[-1], 12))
    delta = 0.01
    cp = compensate_trace(rec, CompensationParams(standoff_mm=0.1, xy_uncertainty_mm=delta))
    slope = cp.to_result()["slope"]
    assert slope["max_slope_deg"] == pytest.approx(np.degrees(np.arcsin(15.0 / R)), abs=0.05)
    # the part really sits delta mm off in x: the vertical standoff errs by about delta * tan(slope)
    actual = np.abs(cp.points[:, 2] - sphere_z(cp.points[:, :2], dx=delta) - 0.1).max()
    assert slope["max_height_error_mm"] == pytest.approx(actual, rel=0.05)
    flat = compensate_trace(AnalyticReconstruction(
        TracePolyline(points=np.column_stack([x, 0 * x, 0 * x + 5.0]), s=x, normals=np.tile([0.0, 0, 1], (len(x), 1))),
        lambda xy: np.full(len(xy), 5.0), np.linspace(0.0, 15.0, 12)), CompensationParams())
    assert flat.to_result()["slope"]["max_height_error_mm"] == 0.0
