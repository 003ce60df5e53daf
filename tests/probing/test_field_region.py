"""The region a board's traces cover: its trace samples, kept per path at the last step asked."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.probing.deviation_prior import path_gradient
from app.probing.field_region import path_samples, sample_traces
from app.reference.boards import board_path, board_traces, s1_part


def cold(path, step_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples from scratch: every about ``step_mm``, both ends included."""
    s = np.linspace(0.0, path.length_mm, max(2, int(math.ceil(path.length_mm / step_mm)) + 1))
    return s, path.at(s), path_gradient(path, s)


def test_kept_samples_are_the_samples_from_scratch_at_every_step_asked_and_read_only():
    part = s1_part()
    paths = [board_path(part, g, 0.05) for g in board_traces(part, 4)]
    for step in (1.0, 1.0, 0.7, 1.0):
        points = sample_traces(paths, step)
        expected = [cold(p, step) for p in paths]
        assert np.array_equal(points.s, np.concatenate([e[0] for e in expected]))
        assert np.array_equal(points.sites.xy, np.concatenate([e[1][:, :2] for e in expected]))
        assert np.array_equal(points.z, np.concatenate([e[1][:, 2] for e in expected]))
        assert np.array_equal(points.sites.grad, np.concatenate([e[2] for e in expected]))
        assert np.array_equal(points.trace, np.repeat(np.arange(len(paths)), [len(e[0]) for e in expected]))
        points.z[:] = 0.0    # the caller's copy: the kept samples do not change
    s, pts, grad = path_samples(paths[0], 1.0)
    with pytest.raises(ValueError):
        pts[0, 0] = 1.0
