"""A real-time mock machine idle for ten minutes at the default liveness window (30 s), then
a 2,000-line print: it runs exactly once, in order, with no LinkError (Marlin and grbl).
Slow by design (``make bench``); ``tests/hardware/test_idle_link.py`` is the fast version."""

from __future__ import annotations

import os
import time

import pytest

from hardware.machine import Machine, MachineProfile
from hardware.mock import MockWorld, register_world, unregister_world
from hardware.protocol import normalized_commands

IDLE_S = float(os.environ.get("CONFORMA_BENCH_IDLE_S", "600"))
PROFILES = {"marlin": MachineProfile(), "grbl": MachineProfile(dispense_on="M8", dispense_off="M9")}
WAIT = {"marlin": "M400", "grbl": "G4 P0"}


@pytest.mark.timeout(IDLE_S + 600)
@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_a_print_after_ten_minutes_idle_runs_exactly_once(dialect):
    name = f"bench-idle-{dialect}"
    world = register_world(name, MockWorld(dialect=dialect, time_scale=1.0, boot_s=0.05))
    try:
        m = Machine(f"mock://{name}", dialect, PROFILES[dialect])  # the default 30 s window
        m.connect()
        world.transcript.reset()
        time.sleep(IDLE_S)
        lines = ["G21", "G90", "G1 X5 F600", WAIT[dialect]] + \
            [f"G1 X{5 + (i % 200) * 0.2:.1f} Y{(i // 200) * 0.5:.1f} F6000" for i in range(1996)]
        started = time.monotonic()
        report = m.stream(lines)
        elapsed = time.monotonic() - started
        assert report.executed == report.total == len(lines) == 2000
        assert world.transcript.commands == normalized_commands([*m.profile.safe_off, *lines])  # safe_off first
        print(f"\n{dialect}: idle {IDLE_S:.0f} s, then {len(lines)} lines in {elapsed:.1f} s, executed once, "
              f"link {report.link_stats}")
        m.disconnect()
    finally:
        unregister_world(name)
