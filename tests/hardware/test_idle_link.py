"""An idle link is not a dead link: a real-time mock machine left idle longer than the
liveness window prints its next program exactly once.  An idle grbl or Marlin says nothing
unless asked (grbl answers ``?``; Marlin prints ``busy:`` only while a command runs, and
temperatures only when the host asked for them with M155), so the window is short here
(``timeout_s``) and the idle time longer; ``tests/bench`` idles ten minutes at the default."""

from __future__ import annotations

import time

import pytest

from hardware.machine import Machine, MachineProfile
from hardware.protocol import normalized_commands

PROFILES = {"marlin": MachineProfile(), "grbl": MachineProfile(dispense_on="M8", dispense_off="M9")}


WAIT = {"marlin": "M400", "grbl": "G4 P0"}  # answered once the motion before it has ended
DWELL = {"marlin": "G4 P300", "grbl": "G4 P0.3"}  # 0.3 s (Marlin P is ms, grbl P is s)


def program(dialect: str, moves: int) -> list[str]:
    """A 0.4 s move whose wait says nothing until it ends (the first answer comes late), then
    short moves."""
    return ["G21", "G90", "G1 X4 F600", WAIT[dialect]] + \
        [f"G1 X{4 + i * 0.5:.1f} Y{i % 3} F6000" for i in range(1, moves + 1)]


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
def test_a_print_after_an_idle_longer_than_the_liveness_window_runs_exactly_once(make_world, dialect):
    url, world = make_world(dialect=dialect, time_scale=1.0, boot_s=0.02)
    m = Machine(url, dialect, PROFILES[dialect], timeout_s=0.6, boot_wait_s=0.3, boot_quiet_s=0.02, poke_s=0.3)
    m.connect()
    world.transcript.reset()
    time.sleep(0.8)  # idle: longer than the 0.6 s window
    lines = program(dialect, 20)
    report = m.stream(lines)  # LinkError("no reply for 0.6 s") before the fix
    assert report.executed == report.total == len(lines)
    # exactly once, in order, after the safe_off every program starts with
    assert world.transcript.commands == normalized_commands([*m.profile.safe_off, *lines])
    assert m.state == "idle" and m.link.healthy
    time.sleep(0.8)  # idle again, then a console dwell: its answer comes 0.3 s later (no reports)
    assert m.send(DWELL[dialect]).status == "ok"
    assert m.move(x=13.5, feed_mm_min=600)[0] == pytest.approx(13.5, abs=1e-3)  # 0.05 s
    m.disconnect()
