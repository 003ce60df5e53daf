"""The print grid on a machine: swaths, the scan raster, cell means, prediction fill, substrate."""

from __future__ import annotations

import numpy as np
import pytest

from app.jetting import DropParams, FlowParams, JettingError, drop_kernel
from app.jetting.flow import flow_layer
from app.jetting.kernel import deposit
from app.jetting.machine_grid import (
    Grid,
    cell_means,
    fill_missing,
    predicted_heights,
    raster_waypoints,
    substrate_map,
    swaths,
)
from app.probing.scan_path import sample_positions

GRID = Grid((6, 10), 0.1, (2.0, 3.0))


def test_swaths_cut_the_pattern_by_nozzles_and_skip_empty_ones():
    pattern = np.zeros((6, 10), dtype=bool)
    pattern[:, 1] = pattern[2, 9] = True
    cut = swaths(pattern, 4)
    assert [s.first_col for s in cut] == [0, 8]  # columns 4..7 hold no drop
    assert np.array_equal(cut[0].bits, pattern[:, :4]) and np.array_equal(cut[1].bits, pattern[:, 8:])
    with pytest.raises(JettingError):
        swaths(pattern, 0)


def test_the_raster_puts_the_spot_on_every_column_centre_and_bins_back_exactly():
    spot = (1.5, -0.7)
    w = raster_waypoints(GRID, spot, 4.0)
    assert w.shape == (20, 3) and np.allclose(w[:, 2], 4.0)
    assert np.allclose(w[::2, 0] + spot[0], GRID.x(np.arange(10)))
    assert w[0, 1] < w[1, 1] and w[2, 1] > w[3, 1]  # serpentine
    carriage = sample_positions(w, 10.0, 4000, 2000.0)
    xy = carriage[:, :2] + spot
    truth = np.add.outer(np.arange(6) * 1.0, np.arange(10) * 0.1)  # height of cell (i, j)
    col = np.rint((xy[:, 0] - 2.0) / 0.1).astype(int)
    row = np.rint((xy[:, 1] - 3.0) / 0.1).astype(int)
    inside = (row >= 0) & (row < 6) & (col >= 0) & (col < 10)
    h = np.where(inside, truth[np.clip(row, 0, 5), np.clip(col, 0, 9)], 99.0)
    h[::7] = np.nan  # dropouts
    mean, count = cell_means(xy, h, GRID)
    assert np.allclose(mean, truth) and (count > 0).all()


def test_cells_without_a_sample_take_the_models_prediction():
    drop, flow = DropParams(), FlowParams()
    kernel = drop_kernel(drop)
    before = np.zeros((12, 12))
    pattern = np.zeros((12, 12), dtype=bool)
    pattern[3:9, 3:9] = True
    predicted = predicted_heights(before, pattern, kernel, flow)
    d = deposit(pattern.astype(float), kernel)
    assert np.allclose(predicted, flow_layer(before + d, d, np.full((12, 12), flow.mobility), flow).surface)
    measured = predicted + 1e-4
    measured[5, 5] = np.nan
    filled, count = fill_missing(measured, predicted)
    assert count == 1 and filled[5, 5] == predicted[5, 5] and filled[0, 0] == measured[0, 0]


def test_the_substrate_is_smoothed_and_a_blind_scan_is_refused():
    rng = np.random.default_rng(0)
    i, j = np.indices((40, 40))
    bed = 1e-3 * i - 4e-4 * j + 2e-3 * np.sin(j / 30.0)  # tilted, wavy over 19 mm
    scan = bed + 2e-4 * rng.standard_normal((40, 40))
    scan[10, 10] = np.nan
    smooth = substrate_map(scan, 0.1, 0.5)
    error = np.abs(smooth - bed)  # the noise gone; what is left: the curvature under the Gaussian, edges
    assert error.mean() < 3e-5 and error.max() < 2e-4 < np.nanmax(np.abs(scan - bed)) / 2.5
    with pytest.raises(JettingError):
        substrate_map(np.full((4, 4), np.nan), 0.1)
