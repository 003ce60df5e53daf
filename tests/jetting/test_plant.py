import numpy as np
import pytest

from app.jetting.errors import JettingError
from app.jetting.kernel import drop_kernel
from app.jetting.params import DropParams, FlowParams, PlantParams
from app.jetting.plant import Plant

DROP = DropParams()
SHAPE = (10, 40)


def run(plant_params, layers=5, flow=None):
    flow = FlowParams() if flow is None else flow
    plant = Plant(SHAPE, drop_kernel(DROP), flow, plant_params)
    pattern = np.zeros(SHAPE, dtype=bool)
    pattern[2:8, 2:38] = True
    for _ in range(layers):
        plant.print_layer(pattern)
    return plant, pattern


def test_same_seed_same_run_other_seed_other_run():
    a, _ = run(PlantParams(seed=7, nozzle_spread=0.05, sensor_noise_um=0.3))
    b, _ = run(PlantParams(seed=7, nozzle_spread=0.05, sensor_noise_um=0.3))
    c, _ = run(PlantParams(seed=8, nozzle_spread=0.05, sensor_noise_um=0.3))
    np.testing.assert_array_equal(a.heights, b.heights)
    np.testing.assert_array_equal(a.measure(), b.measure())
    assert not np.array_equal(a.heights, c.heights)


def test_noise_free_plant_deposits_exactly_the_jetted_volume():
    plant, pattern = run(PlantParams(nozzle_spread=0, drop_noise=0), layers=7)
    volume = plant.heights.sum() * DROP.pitch_mm**2
    assert volume == pytest.approx(7 * pattern.sum() * DROP.volume_mm3, rel=1e-12)


def test_dead_nozzle_leaves_its_column_empty_without_flow():
    plant, _ = run(PlantParams(dead_nozzles=(5,), n_nozzles=16), flow=FlowParams(flow_steps=0))
    assert not plant.heights[:, 5].any() and not plant.heights[:, 21].any()  # 21 % 16 == 5
    assert plant.heights[4, 6] > 0


def test_nozzle_spread_sets_the_column_volume_spread():
    plant = Plant((4, 4000), drop_kernel(DROP), FlowParams(), PlantParams(nozzle_spread=0.04, n_nozzles=4000))
    assert np.std(plant.column_volume) == pytest.approx(0.04, rel=0.1)


def test_sensor_noise_level():
    plant = Plant((200, 200), drop_kernel(DROP), FlowParams(), PlantParams(sensor_noise_um=0.5))
    assert np.std(plant.measure()) * 1e3 == pytest.approx(0.5, rel=0.05)


def test_bad_plant_parameters():
    with pytest.raises(JettingError):
        Plant(SHAPE, drop_kernel(DROP), FlowParams(), PlantParams(dead_nozzles=(999,)))
    with pytest.raises(JettingError):
        Plant(SHAPE, drop_kernel(DROP), FlowParams(), PlantParams(nozzle_spread=-1))
