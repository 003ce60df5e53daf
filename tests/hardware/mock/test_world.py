"""Mock world configuration: URL options, registry, bad input."""

from __future__ import annotations

import pytest

from hardware.errors import InvalidConfig
from hardware.mock import (
    FaultConfig,
    MockWorld,
    get_world,
    parse_mock_options,
    register_world,
    unregister_world,
    world_from_url,
)


def test_url_options_are_typed_and_applied():
    world = world_from_url("mock://opts1?dialect=grbl&time_scale=0.5&checksum_rate=0.01"
                           "&disconnect_at_line=500&seed=7&advanced_ok=0&probe_noise_mm=0.02")
    try:
        assert world is get_world("opts1")
        assert world.dialect == "grbl" and world.time_scale == 0.5
        assert world.faults.checksum_rate == 0.01 and world.faults.disconnect_at_line == 500
        assert world.faults.seed == 7 and world.advanced_ok is False
        assert world.probe_noise_mm == 0.02
    finally:
        unregister_world("opts1")


def test_registered_world_is_reused_and_dialect_must_match():
    world = register_world("opts2", MockWorld(dialect="marlin"))
    try:
        assert world_from_url("mock://opts2?drop_ok_rate=0.5") is world
        assert world.faults.drop_ok_rate == 0.5
        with pytest.raises(InvalidConfig) as info:
            world_from_url("mock://opts2?dialect=grbl")
        assert info.value.field == "dialect"
    finally:
        unregister_world("opts2")


@pytest.mark.parametrize("query,field", [
    ("dialect=smoothie", "dialect"),
    ("checksum_rate=abc", "port.checksum_rate"),
    ("checksum_rate=1.5", "port.checksum_rate"),
    ("time_scale=-1", "port.time_scale"),
    ("disconnect_at_line=ten", "port.disconnect_at_line"),
    ("colour=blue", "port.colour"),
    ("advanced_ok=maybe", "port.advanced_ok"),
    ("time_scale=nan", "port.time_scale"),
    ("rx_buffer=0", "port.rx_buffer"),
])
def test_malformed_options_name_the_field(query, field):
    with pytest.raises(InvalidConfig) as info:
        parse_mock_options(query)
    assert info.value.field == field


def test_unknown_dialect_in_world():
    with pytest.raises(InvalidConfig):
        MockWorld(dialect="reprap")


def test_uniform_fault_plan():
    plan = FaultConfig.uniform(0.01, seed=3)
    rates = [plan.checksum_rate, plan.drop_ok_rate, plan.duplicate_ok_rate, plan.resend_rate,
             plan.garbage_rate, plan.busy_rate, plan.slow_rate]
    assert rates == [0.01] * 7 and plan.seed == 3 and plan.disconnect_at_line is None
