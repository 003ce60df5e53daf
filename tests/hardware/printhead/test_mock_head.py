"""The mock head driver on the mock machine: protocol, firing from the carriage's position,
nozzle volumes, dead nozzles, the UV cure and what the mock height sensor reads back."""

from __future__ import annotations

import numpy as np
import pytest

from app.jetting.flow import flow_layer
from app.jetting.params import FlowParams
from hardware.height_sensor import HeightSensor
from hardware.height_sensor.mock import unregister_sensor
from hardware.machine import Machine, MachineProfile
from hardware.printhead import HeadRejected, PrintHead, hdp
from hardware.printhead.ink import cap_kernel
from hardware.printhead.mock import get_head, head_from_url, unregister_head

PITCH = 25.4 / 300
OFFSET = (20.0, -15.0)


@pytest.fixture
def rig(make_world):
    """``rig(head_options) -> (machine, head, mock head, world)`` on a fresh mock machine."""
    made = []

    def make(options: str = ""):
        url, world = make_world()
        name = url.removeprefix("mock://")
        machine = Machine(url)
        machine.connect()
        machine.home()
        head = PrintHead(f"head://{name}?offset={OFFSET[0]},{OFFSET[1]}&field=0,0,200,200&{options}".rstrip("&"))
        head.connect()
        made.append((name, head))
        return machine, head, get_head(name), world

    yield make
    for name, head in made:
        head.close()
        unregister_head(name)


def swath_moves(x_carriage: float, y_from: float, y_to: float, z: float = 5.0) -> list[str]:
    return ["G90", f"G1 X{x_carriage:.4f} Y{y_from:.4f} Z{z:.3f} F6000", f"G1 Y{y_to:.4f} F3000", "M400"]


def test_a_bitmap_round_trips_and_a_damaged_one_is_refused(rig):
    bits = np.random.default_rng(1).random((7, 13)) < 0.5
    text, crc = hdp.pack_bitmap(bits)
    assert np.array_equal(hdp.unpack_bitmap(text, 7, 13, crc), bits)
    _, head, _, _ = rig()
    with pytest.raises(HeadRejected, match="checksum") as info:
        head.command(f"LOAD,1.0,7,0,13,{'0' * 8},{text}")
    assert info.value.code == 23
    with pytest.raises(HeadRejected, match="status"):
        head.arm()  # nothing loaded
    with pytest.raises(HeadRejected, match="invalid parameter"):
        head.load(np.ones((2, 400), dtype=bool), 1.0, 0)  # 400 nozzles on a 384-nozzle head


def test_each_drop_lands_once_at_its_cell_with_its_nozzles_volume(rig):
    machine, head, mock, _ = rig("spread=0.1&drop_noise=0&seed=7&rows=2&row_gap_um=550")
    assert head.info.nozzles == 384 and head.info.rows == 2
    bits = np.random.default_rng(3).random((20, 30)) < 0.6
    first, y0 = 10, 5.0 + 40 * PITCH  # cell row 40 of the field (origin 0, 0)
    col0 = 60  # nozzle `first` over field column 60
    x_carriage = col0 * PITCH - OFFSET[0] - first * PITCH
    assert head.load(bits, y0, first) == bits.sum()
    head.arm()
    y_start = y0 - OFFSET[1] - 1.0  # nozzles 1 mm before row 0
    y_mid = y0 + 9.5 * PITCH - OFFSET[1]  # row 0 of the nozzles halfway through the swath
    machine.stream(swath_moves(x_carriage, y_start, y_mid))
    half = head.status()
    assert half.armed and 0 < half.rows_done < 20  # the lagging nozzle row has not reached row 9
    machine.stream(["G1 Y%.4f F3000" % (y0 + 20 * PITCH - OFFSET[1] + 1.0), "M400"])
    assert head.status().rows_done == 20
    machine.stream(["G1 Y%.4f F3000" % y_start, "M400"])  # back over the swath: nothing fires twice
    assert head.disarm() == bits.sum() == mock.field.drops
    landed = mock.field.liquid / cap_kernel(PITCH, 60.0)[0, 0] / 6e-6  # drop volume units per cell
    factor = 1.0 + 0.1 * np.random.default_rng(7).standard_normal(384)  # the simulation's nozzle draw
    rows, cols = np.nonzero(bits)
    expected = np.zeros((200, 200))
    expected[np.rint((y0 + rows * PITCH) / PITCH).astype(int), col0 + cols] = factor[first + cols]
    assert np.allclose(landed, expected, atol=1e-9)


def test_a_dead_nozzle_prints_nothing_and_can_fail_mid_run(rig):
    machine, head, mock, world = rig("drop_noise=0&spread=0")
    bits = np.ones((4, 8), dtype=bool)

    def pass_once() -> np.ndarray:
        before = mock.field.liquid.copy()
        head.load(bits, 2.0, 0)
        head.arm()
        machine.stream(swath_moves(100 * PITCH - OFFSET[0], 2.0 - OFFSET[1] - 1.0, 2.0 - OFFSET[1] + 2.0))
        head.disarm()
        return (mock.field.liquid - before).sum(axis=0)[100:108] > 0

    assert pass_once().all()
    name = head.url.removeprefix("head://").split("?")[0]
    head_from_url(f"head://{name}?dead=3")
    printed = pass_once()
    assert not printed[3] and printed[[0, 1, 2, 4, 5, 6, 7]].all()


def test_the_uv_lamp_cures_the_ink_by_the_published_flow_and_the_sensor_reads_it(rig):
    machine, head, mock, world = rig("drop_noise=0&spread=0.05&cure_s=0.2")
    bits = np.zeros((30, 30), dtype=bool)
    bits[5:25, 5:25] = True
    head.load(bits, 3.0, 0)
    head.arm()
    machine.stream(swath_moves(50 * PITCH - OFFSET[0], 3.0 - OFFSET[1] - 1.0, 3.0 + 31 * PITCH - OFFSET[1] + 1.0))
    head.disarm()
    liquid = mock.field.liquid.copy()
    machine.stream(["M42 P6 S255", "G4 P100", "M42 P6 S0"])  # too short a dose: still liquid
    assert mock.cures == 0 and np.array_equal(mock.field.liquid, liquid)
    machine.stream(["M42 P6 S255", "G4 P250", "M42 P6 S0"])
    assert mock.cures == 1 and not mock.field.liquid.any()
    reference = flow_layer(liquid, liquid, np.full(liquid.shape, 0.5), FlowParams()).surface
    assert np.allclose(mock.field.solid, reference, atol=1e-12)
    assert mock.field.solid.sum() == pytest.approx(liquid.sum(), rel=1e-12)
    # the LK-G mock (no noise) sees the cured top at a printed cell, 0 beside the print
    name = head.url.removeprefix("head://").split("?")[0]
    sensor = HeightSensor(f"lkg://{name}?noise_mm=0&offset=30,5,-10&resolution_mm=0.0001", rate_hz=2000)
    sensor.connect()
    try:
        row, col = int(np.rint(3.0 / PITCH)) + 10, 50 + 10
        machine.move(col * PITCH - 30, row * PITCH - 5, 10.0)  # spot on the cell, zero at the bed
        assert sensor.measure() == pytest.approx(mock.field.solid[row, col], abs=1e-4)
        machine.move(col * PITCH - 30 + 5.0, row * PITCH - 5, 10.0)
        assert sensor.measure() == pytest.approx(0.0, abs=1e-4)
    finally:
        sensor.close()
        unregister_sensor(name)


def test_on_grbl_the_lamp_is_the_flood_coolant_output(make_world):
    url, world = make_world(dialect="grbl")
    name = url.removeprefix("mock://")
    machine = Machine(url, "grbl", MachineProfile(), boot_quiet_s=0.01, timeout_s=10, poke_s=0.05)
    machine.connect()
    head = PrintHead(f"head://{name}?offset={OFFSET[0]},{OFFSET[1]}&field=0,0,100,100&cure=M8&cure_s=0.2")
    head.connect()
    try:
        head.load(np.ones((3, 3), dtype=bool), 2.0, 0)
        machine.stream(["G90", f"G1 X{50 * PITCH - OFFSET[0]:.4f} Y{2.0 - OFFSET[1] - 1:.4f} Z5 F6000"])
        head.arm()
        machine.stream([f"G1 Y{2.0 - OFFSET[1] + 2:.4f} F3000"])
        assert head.disarm() == 9
        mock = get_head(name)
        machine.stream(["M8", "G4 P0.3", "M9"])  # grbl's dwell is in seconds
        assert mock.cures == 1 and mock.field.drops == 9 and not mock.field.liquid.any()
    finally:
        head.close()
        unregister_head(name)
