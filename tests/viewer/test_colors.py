"""Colour maps of the view."""

from __future__ import annotations

import numpy as np

from app.viewer.colors import deviation_colors, height_colors


def test_deviation_map_is_white_at_zero_and_symmetric():
    c = deviation_colors(np.array([-0.2, -0.1, 0.0, 0.1, 0.2, 5.0]), limit_mm=0.2)
    assert c.dtype == np.uint8 and c.shape == (6, 3)
    assert c[2].tolist() == [247, 247, 247]
    assert c[0].tolist() == [33, 102, 172] and c[4].tolist() == [178, 24, 43]
    assert c[5].tolist() == c[4].tolist()  # clipped beyond the limit
    assert c[4, 0] > c[4, 2] and c[0, 2] > c[0, 0]  # red above, blue below
    # half-way colours are the mid points between white and the ends
    assert np.allclose(c[3], np.rint((np.array([247, 247, 247]) + [178, 24, 43]) / 2), atol=1)


def test_deviation_map_defaults_to_the_largest_magnitude_and_handles_flat_input():
    assert deviation_colors(np.array([-0.5, 0.25]))[0].tolist() == [33, 102, 172]
    assert np.all(deviation_colors(np.zeros(3)) == 247)
    assert deviation_colors(np.array([np.nan]))[0].tolist() == [247, 247, 247]


def test_height_map_runs_from_dark_to_bright():
    c = height_colors(np.linspace(0, 1, 11), 0.0, 1.0)
    brightness = c.astype(float).sum(axis=1)
    assert c[0].tolist() == [48, 18, 59] and c[-1].tolist() == [250, 240, 30]
    assert brightness[-1] > brightness[0]
    assert np.all(height_colors(np.array([3.0, 4.0]), 2.0, 2.0) == height_colors(np.array([0.5]), 0, 1)[0])
