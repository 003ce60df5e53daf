"""work_estimate: the work of a surface fit with a control net, checked against the algorithm."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.fitting import interpolate_surface
from app.reconstruction.surface_fit.work import work_estimate


def test_banded_normal_equations() -> None:
    work = work_estimate((20.0, 10.0), 3, separable=False)
    assert work.unknowns == 200
    assert work.bandwidth == 3 * 10 + 3  # the shorter direction sets the band
    assert work.band_bytes == 8 * 200 * 34
    assert work.flops == 200 * 33**2
    assert work.inversion_samples == (6 * 17 + 1) * (6 * 7 + 1)  # 2 * degree samples per span


def test_separable_fit_has_no_band() -> None:
    work = work_estimate((20.0, 10.0), 3, separable=True)
    assert (work.bandwidth, work.band_bytes, work.flops) == (0.0, 0.0, 0.0)
    assert work.inversion_samples == work_estimate((20.0, 10.0), 3, separable=False).inversion_samples


def test_low_degree_samples_at_least_four_per_span_and_one_span_per_direction() -> None:
    assert work_estimate((5.0, 2.0), 1, separable=True).inversion_samples == (4 * 4 + 1) * (4 * 1 + 1)
    assert work_estimate((2.0, 2.0), 3, separable=True).inversion_samples == (6 + 1) * (6 + 1)


@pytest.mark.parametrize(("shape", "degree"), [((8, 6), 3), ((5, 9), 2), ((4, 4), 1)])
def test_inversion_samples_match_the_surface_inversion(shape: tuple[int, int], degree: int) -> None:
    x, y = np.meshgrid(np.linspace(0.0, 10.0, shape[0]), np.linspace(0.0, 7.0, shape[1]), indexing="ij")
    surface = interpolate_surface(np.stack([x, y, np.sin(x) * np.cos(y)], axis=-1), degree, degree)
    assert surface.control_points.shape[:2] == shape
    uv, _ = surface._samples  # the sample NurbsSurface.invert starts from
    assert work_estimate((float(shape[0]), float(shape[1])), degree, separable=True).inversion_samples == len(uv)
