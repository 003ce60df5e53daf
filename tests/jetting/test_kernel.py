import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.jetting.kernel import (
    cap_height,
    deposit,
    deposit_adjoint,
    drop_kernel,
)
from app.jetting.params import DropParams


@settings(max_examples=25, deadline=None)
@given(dpi=st.floats(100, 1200), diameter=st.floats(10, 300), volume=st.floats(0.5, 60))
def test_kernel_volume_equals_drop_volume(dpi, diameter, volume):
    drop = DropParams(dpi=dpi, drop_diameter_um=diameter, drop_volume_pl=volume)
    kernel = drop_kernel(drop)
    assert kernel.volume() == pytest.approx(drop.volume_mm3, rel=1e-12)
    assert np.all(kernel.heights_mm >= 0)
    np.testing.assert_allclose(kernel.heights_mm, kernel.heights_mm.T, rtol=1e-12)
    np.testing.assert_allclose(kernel.heights_mm, kernel.heights_mm[::-1, ::-1], rtol=1e-12)


@given(radius=st.floats(1e-3, 1.0), volume=st.floats(1e-7, 1e-1))
def test_cap_height_solves_cap_volume(radius, volume):
    h = cap_height(radius, volume)
    assert np.pi * h * (3 * radius**2 + h**2) / 6 == pytest.approx(volume, rel=1e-9)


def test_seed_drop_fits_one_cell_at_300_dpi_and_spreads_at_600():
    # 60 um spread diameter < 84.7 um pitch: the whole cap lies in its landing cell
    assert drop_kernel(DropParams(dpi=300)).heights_mm.shape == (1, 1)
    k600 = drop_kernel(DropParams(dpi=600)).heights_mm
    assert k600.shape == (3, 3) and k600[0, 0] == 0.0 and k600[0, 1] > 0.0


def test_one_full_layer_is_volume_over_cell_area():
    drop = DropParams(dpi=600)
    grid = np.zeros((20, 20))
    grid[4:16, 4:16] = 1.0
    heights = deposit(grid, drop_kernel(drop))
    assert heights[8:12, 8:12] == pytest.approx(drop.layer_mm, rel=1e-12)
    assert heights.sum() * drop.pitch_mm**2 == pytest.approx(144 * drop.volume_mm3, rel=1e-12)


def test_deposit_adjoint_is_transpose():
    rng = np.random.default_rng(1)
    kernel = drop_kernel(DropParams(dpi=900, drop_diameter_um=100))
    f, y = rng.random((15, 17)), rng.random((15, 17))
    assert np.sum(deposit(f, kernel) * y) == pytest.approx(np.sum(f * deposit_adjoint(y, kernel)), rel=1e-12)
