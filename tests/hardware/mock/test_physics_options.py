"""Probe-physics options of the mock world: defaults, URL round trip, refusals."""

from __future__ import annotations

import pytest

from hardware.errors import InvalidConfig
from hardware.mock import MockPad, MockSphere, MockTool, MockWorld, parse_mock_options, unregister_world, world_from_url


def test_defaults_are_the_ideal_probe():
    world = MockWorld()
    assert world.stylus_radius_mm == 0.0 and world.pretravel_mm == 0.0
    assert world.pretravel_sd_mm == 0.0 and world.pretravel_lobing_mm == 0.0
    assert world.drift_mm_per_min == 0.0 and world.touchoff_sd_mm == 0.0
    assert world.tools == () and world.pad is None and world.sphere is None
    assert world.active_tool == 0 and world.stats.machine_time_s == 0.0
    assert world.stats.collisions == 0 and world.drift_mm() == 0.0


def test_url_options_round_trip():
    world = world_from_url("mock://phys1?stylus_radius_mm=0.5&pretravel_mm=0.015"
                           "&pretravel_sd_mm=0.002&pretravel_lobing_mm=0.003"
                           "&drift_mm_per_min=0.001&touchoff_sd_mm=0.0005"
                           "&tool1=12.3,-4.1,-8.7,0.8&tool2=-10,0,-5,1.2"
                           "&pad=100,10,5,20&sphere=120,10,12.7,25.4")
    try:
        assert world.stylus_radius_mm == 0.5 and world.pretravel_mm == 0.015
        assert world.pretravel_sd_mm == 0.002 and world.pretravel_lobing_mm == 0.003
        assert world.drift_mm_per_min == 0.001 and world.touchoff_sd_mm == 0.0005
        assert world.tools == (MockTool((12.3, -4.1, -8.7), 0.8), MockTool((-10.0, 0.0, -5.0), 1.2))
        assert world.pad == MockPad((100.0, 10.0, 5.0), 20.0)
        assert world.sphere == MockSphere((120.0, 10.0, 12.7), 25.4)
        # a later URL updates one tool and keeps the other
        assert world_from_url("mock://phys1?tool2=0,0,-1,0.5") is world
        assert world.tools[0].offset_mm == (12.3, -4.1, -8.7)
        assert world.tools[1] == MockTool((0.0, 0.0, -1.0), 0.5)
    finally:
        unregister_world("phys1")


@pytest.mark.parametrize("query,field", [
    ("stylus_radius_mm=-0.1", "port.stylus_radius_mm"),
    ("stylus_radius_mm=abc", "port.stylus_radius_mm"),
    ("pretravel_mm=inf", "port.pretravel_mm"),
    ("pretravel_sd_mm=-1", "port.pretravel_sd_mm"),
    ("pretravel_lobing_mm=2", "port.pretravel_lobing_mm"),
    ("drift_mm_per_min=nan", "port.drift_mm_per_min"),
    ("touchoff_sd_mm=-0.001", "port.touchoff_sd_mm"),
    ("tool1=1,2,3", "port.tool1"),
    ("tool1=1,2,3,0", "port.tool1"),
    ("tool1=a,2,3,1", "port.tool1"),
    ("tool9=1,2,3,1", "port.tool9"),
    ("pad=1,2,3", "port.pad"),
    ("pad=1,2,3,-5", "port.pad"),
    ("sphere=1,2,3,0", "port.sphere"),
    ("sphere=1,2,nan,10", "port.sphere"),
])
def test_bad_physics_options_name_the_option(query, field):
    with pytest.raises(InvalidConfig) as info:
        parse_mock_options(query)
    assert info.value.field == field


def test_tools_must_be_contiguous():
    with pytest.raises(InvalidConfig) as info:
        world_from_url("mock://phys2?tool2=0,0,-1,1")
    unregister_world("phys2")
    assert info.value.field == "port.tool2" and "tool1" in info.value.message


def test_bad_values_in_code_are_refused():
    with pytest.raises(InvalidConfig) as info:
        MockWorld(stylus_radius_mm=-1.0)
    assert info.value.field == "stylus_radius_mm"
    with pytest.raises(InvalidConfig):
        MockTool((0.0, 0.0), 1.0)
    with pytest.raises(InvalidConfig):
        MockWorld(tools=((1, 2, 3),))
