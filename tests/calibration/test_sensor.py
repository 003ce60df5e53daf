"""The height sensor's sphere-raster fit and the time offset's share of its uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from app.calibration.sensor import fit_sphere_scan, with_time_offset_sd

CENTRE = (50.0, 20.0, 4.0)
RADIUS = 6.0
OFFSET = (30.0, 5.0)  # the spot, from the carriage (mm)
SPEED = 10.0  # mm/s along each line


def _raster(lines: int, tau_error_s: float, noise_mm: float = 0.0, seed: int = 0):
    """A serpentine raster over the cap (as the calibration job scans it): the carriage
    positions the host paired with each value when its time offset is off by ``tau_error_s``
    (n, 3), the sphere's heights at the true spots (n,), and each sample's direction (n,)."""
    rng = np.random.default_rng(seed)
    carriage, heights, along = [], [], []
    for i, dy in enumerate(np.linspace(-0.35, 0.35, lines) * RADIUS):
        sign = 1.0 if i % 2 == 0 else -1.0
        x = CENTRE[0] - OFFSET[0] + sign * np.linspace(-0.45, 0.45, 181) * RADIUS
        true = np.column_stack([x, np.full_like(x, CENTRE[1] - OFFSET[1] + dy), np.full_like(x, 1.0)])
        d2 = (true[:, 0] + OFFSET[0] - CENTRE[0]) ** 2 + (true[:, 1] + OFFSET[1] - CENTRE[1]) ** 2
        heights.append(CENTRE[2] + np.sqrt(RADIUS ** 2 - d2) + rng.normal(0.0, noise_mm, len(x)))
        paired = true.copy()
        paired[:, 0] -= sign * SPEED * tau_error_s  # the value is paired with where the carriage was d earlier
        carriage.append(paired)
        along.append(np.full(len(x), sign))
    return np.concatenate(carriage), np.concatenate(heights), np.concatenate(along)


def test_the_sphere_fit_recovers_the_offset_from_a_true_raster():
    carriage, heights, _ = _raster(9, 0.0, noise_mm=0.0005)
    fit = fit_sphere_scan(carriage, heights, CENTRE, RADIUS, (30.2, 4.9))
    assert fit["o_x"] == pytest.approx(OFFSET[0], abs=1e-4) and fit["o_y"] == pytest.approx(OFFSET[1], abs=1e-4)


def test_a_time_offset_off_by_its_sd_moves_the_offset_within_the_stated_sd():
    """Nine lines, five one way: a time offset 20 ms off moves o_x by ~1/9 of the 0.2 mm line
    shift; the fit alone states well under a micrometre, with the time offset's sd the stated
    sd covers the error."""
    tau_error = 0.020
    carriage, heights, along = _raster(9, tau_error, noise_mm=0.0005)
    fit = fit_sphere_scan(carriage, heights, CENTRE, RADIUS, (30.2, 4.9))
    error = fit["o_x"] - OFFSET[0]
    assert abs(error) == pytest.approx(SPEED * tau_error * abs(along.mean()), rel=0.25)
    assert abs(error) > 3 * fit["sd_o_x"]  # the fit's own sd does not see it
    stated = with_time_offset_sd(fit, carriage, heights, along, SPEED, tau_error, CENTRE, RADIUS)
    assert abs(error) <= 1.5 * stated["sd_o_x"]
    assert stated["sd_o_x"] == pytest.approx(SPEED * tau_error * abs(along.mean()), rel=0.3)
    assert stated["o_x"] == fit["o_x"] and stated["sd_o_y"] >= fit["sd_o_y"]
