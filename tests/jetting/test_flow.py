import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.jetting.flow import flow_layer, mobility_map, substrate_tilt
from app.jetting.params import FlowParams


def random_layer(seed, shape=(12, 14)):
    rng = np.random.default_rng(seed)
    base = rng.random(shape) * 0.02
    liquid = rng.random(shape) * 0.004 * (rng.random(shape) > 0.3)
    return base, liquid


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), steps=st.integers(0, 4), tau=st.floats(0, 10),
       mobility=st.floats(0, 1))
def test_flow_conserves_mass_and_only_moves_liquid(seed, steps, tau, mobility):
    base, liquid = random_layer(seed)
    flow = FlowParams(threshold_um=tau, mobility=mobility, flow_steps=steps)
    result = flow_layer(base + liquid, liquid, np.full(base.shape, mobility), flow)
    assert result.surface.sum() == pytest.approx((base + liquid).sum(), rel=1e-12, abs=1e-15)
    assert np.all(result.surface >= base - 1e-15)  # cured material never flows


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), steps=st.integers(1, 3))
def test_transport_operator_reproduces_flow_and_is_column_stochastic(seed, steps):
    base, liquid = random_layer(seed)
    flow = FlowParams(threshold_um=1.0, mobility=0.8, flow_steps=steps)
    result = flow_layer(base + liquid, liquid, np.full(base.shape, 0.8), flow)
    op = result.transport
    np.testing.assert_allclose(base + op.apply(liquid), result.surface, atol=1e-15)
    np.testing.assert_allclose(op.adjoint(np.ones(base.shape)), 1.0, atol=1e-12)  # columns sum to 1
    rng = np.random.default_rng(seed)
    x, y = rng.random(base.shape), rng.random(base.shape)
    assert np.sum(op.apply(x) * y) == pytest.approx(np.sum(x * op.adjoint(y)), rel=1e-12)
    dense = np.stack([op.apply(e.reshape(base.shape)).ravel() for e in np.eye(base.size)], axis=1)
    assert np.linalg.norm(dense, 2) <= op.norm_bound() + 1e-12


def test_no_flow_below_threshold_and_flow_above():
    base = np.zeros((5, 5))
    liquid = np.zeros((5, 5))
    liquid[2, 2] = 0.002  # 2 um bump
    below = flow_layer(base + liquid, liquid, np.full((5, 5), 1.0), FlowParams(threshold_um=3.0))
    np.testing.assert_array_equal(below.surface, base + liquid)
    above = flow_layer(base + liquid, liquid, np.full((5, 5), 1.0), FlowParams(threshold_um=1.0, flow_steps=1))
    # full mobility: 1/8 of the 2 um difference to each of the 4 neighbours
    assert above.surface[2, 2] == pytest.approx(0.002 * 0.5)
    assert above.surface[1, 2] == pytest.approx(0.002 / 8)


def test_diagonal_gain_is_the_seeds_one_plus_dg():
    base = np.zeros((7, 7))
    base[:, 4:] = -0.01  # a step down to the right
    liquid = np.zeros((7, 7))
    liquid[:, :4] = 0.001
    result = flow_layer(base + liquid, liquid, np.full((7, 7), 0.5), FlowParams(threshold_um=1.0))
    gain = result.transport.diagonal_gain(liquid)
    dh = result.surface - (base + liquid)
    np.testing.assert_allclose((gain - 1.0)[:, :4] * liquid[:, :4], dh[:, :4], atol=1e-15)
    assert np.all(gain[:, 3] < 1.0)  # the edge cell loses ink


def test_tilt_of_a_plane_and_mobility_above_lambda():
    pitch = 0.1
    x = np.arange(10) * pitch
    plane = np.tile(x * np.tan(0.5), (8, 1))
    tilt = substrate_tilt(plane, plane.shape, pitch)
    np.testing.assert_allclose(tilt, 0.5, atol=1e-12)
    flow = FlowParams(mobility=0.4, slope_lambda_rad=0.2, slope_gain=1.0)
    np.testing.assert_allclose(mobility_map(tilt, flow), 0.4 * (1 + 0.3))
    np.testing.assert_allclose(mobility_map(np.full((2, 2), 0.1), flow), 0.4)
