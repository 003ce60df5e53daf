import numpy as np
import pytest

from app.jetting import (
    ControllerParams,
    DropParams,
    JettingError,
    JettingParams,
    PlantParams,
    TargetSpec,
    estimate_bytes,
    next_layer,
    simulate,
    target_from_spec,
)


def small(kind="mpc", layers=40, seed=0, hole_mm=1.0, **plant):
    return JettingParams(layers=layers, target=TargetSpec(size_mm=2.5, hole_mm=hole_mm),
                         plant=PlantParams(seed=seed, **plant), controller=ControllerParams(kind=kind))


def test_fixed_seed_is_deterministic():
    a, b = simulate(small(layers=8)), simulate(small(layers=8))
    np.testing.assert_array_equal(a.patterns, b.patterns)
    np.testing.assert_array_equal(a.final_heights, b.final_heights)
    assert [r.metrics for r in a.layers] == [r.metrics for r in b.layers]


def test_mpc_flattens_the_part_that_open_loop_roughens():
    open_loop = simulate(small("open_loop", layers=60, hole_mm=0.0, nozzle_spread=0.1))
    mpc = simulate(small("mpc", layers=60, hole_mm=0.0, nozzle_spread=0.1))
    assert mpc.final.metrics.sa_interior_um < open_loop.final.metrics.sa_interior_um / 3
    assert mpc.final.metrics.sa_um < open_loop.final.metrics.sa_um
    # the MPC tracks its reference (fill * layers * layer height) closely
    m = mpc.final.metrics
    assert m.mean_height_um == pytest.approx(m.target_height_um, rel=0.05)
    assert open_loop.patterns.all(axis=0)[open_loop.target.mask].all()


def test_noise_free_open_loop_conserves_the_jetted_volume():
    params = small("open_loop", layers=10, nozzle_spread=0.0, drop_noise=0.0)
    result = simulate(params)
    volume = result.final_heights.sum() * params.drop.pitch_mm**2
    assert volume == pytest.approx(result.patterns.sum() * params.drop.volume_mm3, rel=1e-12)


def test_snapshots_and_records():
    params = JettingParams(layers=6, snapshot_every=2, target=TargetSpec(size_mm=2, hole_mm=0.5))
    result = simulate(params)
    assert result.snapshot_layers == (2, 4, 6)
    assert result.heights.dtype == np.float32 and result.heights.shape[0] == 3
    np.testing.assert_allclose(result.heights[-1], result.final_heights, rtol=1e-6)
    assert [r.layer for r in result.layers] == list(range(1, 7))
    assert {"layer", "sa_um", "sz_um", "rmse_um", "edge_collapse_um", "solve_ms"} <= set(result.layers[0].as_dict())


def test_memory_limit_and_bad_inputs_fail_before_work():
    calls = []
    with pytest.raises(JettingError) as err:
        simulate(JettingParams(drop=DropParams(dpi=600), memory_limit_bytes=10_000_000),
                 progress=lambda done, total: calls.append(done))
    assert err.value.field == "drop.dpi" and not calls
    with pytest.raises(JettingError) as err:
        simulate(JettingParams(controller=ControllerParams(kind="pid")))
    assert err.value.field == "controller"
    with pytest.raises(JettingError):
        simulate(JettingParams(layers=0))
    with pytest.raises(JettingError) as err:
        simulate(JettingParams(drop=DropParams(drop_diameter_um=5000), target=TargetSpec(size_mm=2, hole_mm=0)))
    assert err.value.field == "drop.drop_diameter_um"


def test_estimate_grows_with_resolution():
    p = JettingParams()
    assert estimate_bytes((1181, 1181), p) < p.memory_limit_bytes  # 50 mm at 600 dpi fits
    assert estimate_bytes((2000, 2000), p) > 2 * estimate_bytes((1000, 1000), p) * 0.99


def test_next_layer_drops_where_the_part_is_low():
    params = JettingParams(target=TargetSpec(size_mm=2, hole_mm=0))
    target = target_from_spec(params.target, params.drop)
    step = params.controller.fill * params.drop.layer_mm
    measured = target.mask * (10 * step)
    rows, cols = np.nonzero(target.interior)
    low = (rows[0], cols[0])
    measured[low] -= 3 * step  # a pit
    high = (rows[-1], cols[-1])
    measured[high] += 3 * step  # a bump
    decision = next_layer(measured, target, params)
    assert decision.pattern.shape == target.shape
    assert decision.pattern[low] and not decision.pattern[high]
    assert not decision.pattern[~target.mask].any()
    assert decision.integer_gap >= -1e-9
    with pytest.raises(JettingError) as err:
        next_layer(measured[:-1], target, params)
    assert err.value.field == "measured"


def test_curved_substrate_raises_flow_and_still_conserves_volume():
    params = small("open_loop", layers=30, hole_mm=0.0, nozzle_spread=0.0, drop_noise=0.0)
    target = target_from_spec(params.target, params.drop)
    x = (np.arange(target.shape[1]) - target.shape[1] / 2) * params.drop.pitch_mm
    cylinder = np.tile(np.sqrt(4.0**2 - x**2), (target.shape[0], 1))  # R = 4 mm, up to ~22 deg
    flat = simulate(params, target)
    curved = simulate(params, target, substrate_mm=cylinder)
    volume = curved.final_heights.sum() * params.drop.pitch_mm**2
    assert volume == pytest.approx(curved.patterns.sum() * params.drop.volume_mm3, rel=1e-12)
    assert curved.final.metrics.edge_collapse_um > flat.final.metrics.edge_collapse_um
    with pytest.raises(JettingError):
        simulate(params, target, substrate_mm=cylinder[:-1])
