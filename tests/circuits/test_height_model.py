"""The warp's height model is chosen by the probes: on a probe grid the interpolating bicubic on
the grid, Clough-Tocher and the polyharmonic spline are compared by leaving grid rows and columns
out; on scattered probes Clough-Tocher, the polyharmonic spline and kriging (the deviation GP) by
cross-validation.  The chosen model is checked
against the analytic surface and against interpolants the choice does not know (scipy's radial
basis functions), and its cross-validation error is reported as the model's own uncertainty."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator, RectBivariateSpline
from scipy.spatial import Delaunay

from app.circuits.height_model import height_model_from_points
from app.circuits.heightfield import height_field_from_points
from tests.helpers.warped_surfaces import bow, dome


def _grid_probes(surface, width, height, nx, ny, seed):
    rng = np.random.default_rng(seed)
    gx, gy = np.linspace(0, width, nx), np.linspace(0, height, ny)
    X, Y = np.meshgrid(gx, gy, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), surface(X, Y).ravel() + rng.normal(0, 0.001, X.size)])
    return gx, gy, pts


def _max_error(height, surface, pts, seed=1) -> float:
    """Largest |model - truth| (mm) at 3000 random points inside the probes' convex hull."""
    rng = np.random.default_rng(seed)
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    q = rng.uniform(lo, hi, (3000, 2))
    q = q[Delaunay(pts[:, :2]).find_simplex(q) >= 0]
    return float(np.abs(height(q) - surface(q[:, 0], q[:, 1])).max())


def _field(field):
    return lambda q: field.height(q[:, 0], q[:, 1])


def _rbf(pts, kernel):
    return RBFInterpolator(pts[:, :2], pts[:, 2], kernel=kernel)


def test_grid_probes_on_the_dome_get_a_model_within_2x_of_the_best_interpolant():
    gx, gy, pts = _grid_probes(dome, 60, 40, 13, 9, 0)
    z = pts[:, 2].reshape(len(gx), len(gy))
    shuffled = pts[np.random.default_rng(3).permutation(len(pts))]       # the probes in any order
    field, model = height_model_from_points(shuffled, 1.0)
    assert model.cv == "leave_one_row_out" and set(model.alternatives) == {"grid_bicubic", "clough_tocher",
                                                                            "polyharmonic"}
    assert model.alternatives[model.kind] == min(model.alternatives.values()) and model.kriging is None
    ours = _max_error(_field(field), dome, pts)
    spline = RectBivariateSpline(gx, gy, z, s=0)
    candidates = {"RectBivariateSpline s=0": _max_error(lambda q: spline.ev(q[:, 0], q[:, 1]), dome, pts),
                  "Clough-Tocher resampled": _max_error(_field(height_field_from_points(pts, 1.0)), dome, pts)}
    candidates |= {f"RBF {k}": _max_error(_rbf(pts, k), dome, pts) for k in ("thin_plate_spline", "cubic", "quintic")}
    best = min(candidates.values())
    print(f"\ndome, {model.kind}: max error {ours * 1000:.1f} um; "
          + ", ".join(f"{k} {v * 1000:.1f} um" for k, v in candidates.items()))
    assert ours <= 2.0 * best, (ours, candidates)
    assert ours < candidates["Clough-Tocher resampled"]
    # the reported uncertainty is of the size of the true error (same order, not a chord bound)
    assert model.cv_max_mm > 0 and 0.1 * ours < model.cv_max_mm < 10 * ours


@pytest.mark.parametrize("layout", ["grid", "scattered"])
def test_pcb_bow_is_no_worse_than_the_clough_tocher_model(layout):
    """A bowed board probed on a 7 x 5 grid (the grid's own candidates, as before) or at 35
    scattered points (kriging and the polyharmonic spline beside Clough-Tocher): the chosen model is no worse than
    Clough-Tocher (the model scattered probes had) and than the grid's cross-validation winner."""
    if layout == "grid":
        _, _, pts = _grid_probes(bow, 100, 80, 7, 5, 4)
    else:
        rng = np.random.default_rng(5)
        xy = np.vstack([[[0, 0], [100, 0], [0, 80], [100, 80]], rng.uniform([0, 0], [100, 80], (31, 2))])
        pts = np.column_stack([xy, bow(xy[:, 0], xy[:, 1]) + rng.normal(0, 0.001, len(xy))])
    field, model = height_model_from_points(pts, 1.0)
    ours = _max_error(_field(field), bow, pts)
    clough_tocher = _max_error(_field(height_field_from_points(pts, 1.0)), bow, pts)
    assert ours <= clough_tocher + 1e-6, (model, ours, clough_tocher)
    assert model.alternatives[model.kind] == min(model.alternatives.values())
    if layout == "scattered":
        assert model.cv == "10_fold" and model.kriging is not None and model.kriging["loo_max_mm"] > 0
        assert (model.posterior_sd_max_mm is not None) == (model.kind == "kriging")
        assert ours < 0.5 * clough_tocher          # a smooth model of a smooth bow beats the triangles
    assert ours <= 3 * model.cv_max_mm              # the reported uncertainty covers the true error's size


def test_scattered_probes_choose_by_cross_validation_and_report_it():
    rng = np.random.default_rng(2)
    x, y = rng.uniform(0, 60, 120), rng.uniform(0, 40, 120)
    pts = np.column_stack([x, y, dome(x, y)])
    field, model = height_model_from_points(pts, 1.0)
    assert model.cv == "10_fold" and set(model.alternatives) == {"clough_tocher", "polyharmonic", "kriging"}
    assert model.alternatives[model.kind] == min(model.alternatives.values())
    assert np.isfinite(model.cv_rms_mm) and model.cv_rms_mm <= model.cv_max_mm
    assert _max_error(_field(field), dome, pts) < 5 * model.cv_max_mm


def test_a_fitted_surfaces_thousands_of_samples_keep_clough_tocher():
    from app.circuits.height_model import KRIGING_MAX_POINTS

    rng = np.random.default_rng(6)
    xy = rng.uniform([0, 0], [60, 40], (KRIGING_MAX_POINTS + 1, 2))
    _, model = height_model_from_points(np.column_stack([xy, bow(xy[:, 0], xy[:, 1])]), 2.0)
    assert model.kind == "clough_tocher" and model.kriging is None and model.cv == "holdout_10pct"
