"""The warp's height model is chosen by the probes: on a probe grid the interpolating bicubic on
the grid and Clough-Tocher are compared by leaving grid rows and columns out; the chosen one is
the closer to the true part (checked against the analytic surface), and its cross-validation
error is reported as the model's own uncertainty."""

from __future__ import annotations

import numpy as np

from app.circuits.heightfield import height_field_from_points, height_model_from_points


def dome(x, y):
    """A 13 mm elliptic dome with 0.15 mm waviness (mm)."""
    base = 13.0 * np.sqrt(np.clip(1 - ((x - 30) / 45) ** 2 - ((y - 20) / 32) ** 2, 0, None))
    return base + 0.15 * np.sin(2 * np.pi * x / 17) * np.cos(2 * np.pi * y / 13)


def _true_error(field) -> float:
    rng = np.random.default_rng(1)
    x, y = rng.uniform(2, 58, 4000), rng.uniform(2, 38, 4000)
    return float(np.abs(field.height(x, y) - dome(x, y)).max())


def test_grid_probes_get_the_grid_bicubic_and_it_is_closer_to_the_part():
    rng = np.random.default_rng(0)
    gx, gy = np.linspace(0, 60, 13), np.linspace(0, 40, 9)
    X, Y = np.meshgrid(gx, gy, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), dome(X, Y).ravel() + rng.normal(0, 0.001, X.size)])
    rng.shuffle(pts)                                            # the probes in any order
    field, model = height_model_from_points(pts, 1.0)
    assert model.kind == "grid_bicubic" and model.cv == "leave_one_row_out"
    assert model.alternatives["grid_bicubic"] < model.alternatives["clough_tocher"]
    ours, resampled = _true_error(field), _true_error(height_field_from_points(pts, 1.0))
    assert ours < resampled                                     # the choice is the better model of the part
    # the reported uncertainty is of the size of the true error (same order, not a chord bound)
    assert model.cv_max_mm > 0 and 0.1 * ours < model.cv_max_mm < 10 * ours


def test_scattered_probes_keep_clough_tocher_with_their_cross_validation_error():
    rng = np.random.default_rng(2)
    x, y = rng.uniform(0, 60, 120), rng.uniform(0, 40, 120)
    pts = np.column_stack([x, y, dome(x, y)])
    field, model = height_model_from_points(pts, 1.0)
    assert model.kind == "clough_tocher" and model.cv == "10_fold"
    assert np.isfinite(model.cv_rms_mm) and model.cv_rms_mm <= model.cv_max_mm
    assert _true_error(field) < 5 * model.cv_max_mm
