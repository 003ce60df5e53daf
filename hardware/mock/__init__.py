"""Mock printer firmware behind ``mock://`` URLs (Marlin and grbl personalities).

Importing this package registers it with pyserial (``serial.protocol_handler_packages``,
via ``hardware.transport.register_mock_scheme``; the link registers it on its first
``mock://`` URL without importing this package),
so ``serial.serial_for_url("mock://name?dialect=grbl")`` returns a port whose other end is
the firmware of the ``MockWorld`` registered under ``name`` (created on first use).

    world = MockWorld(true_part=mesh, placement=TruePlacement(dx=0.2), probe_noise_mm=0.005,
                      faults=FaultConfig(checksum_rate=0.01, seed=3))
    register_world("bench", world)
    ...  # connect hardware.machine.Machine("mock://bench") and run
    world.transcript.executed_count, world.executed_sha256, world.deposition_log
"""

from __future__ import annotations

from ..transport import register_mock_scheme
from .artifacts import MockPad, MockSphere, MockTool
from .world import (
    HOST_QUERIES,
    DepositedMove,
    FaultConfig,
    MockStats,
    MockWorld,
    Transcript,
    TruePlacement,
    get_world,
    parse_mock_options,
    register_world,
    unregister_world,
    world_from_url,
)


def register_protocol_handler() -> None:
    """Make ``mock://`` known to ``serial.serial_for_url`` (idempotent)."""
    register_mock_scheme()


register_protocol_handler()

__all__ = ["HOST_QUERIES", "DepositedMove", "FaultConfig", "MockPad", "MockSphere", "MockStats",
           "MockTool", "MockWorld",
           "TruePlacement", "Transcript", "get_world", "parse_mock_options", "register_world",
           "register_protocol_handler", "unregister_world", "world_from_url"]
