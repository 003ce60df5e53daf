"""The arguments both machine backends check before anything moves
(``hardware.machine_args``): each refusal names its field and value, and both backends
refuse alike, before they touch a link."""

from __future__ import annotations

import math

import pytest

from hardware.errors import InvalidConfig
from hardware.linuxcnc import LinuxCNCMachine
from hardware.machine import Machine as SerialMachine
from hardware.machine_args import (
    axis_words,
    check_tool,
    probe_down,
    probe_missed,
    probe_toward,
    program_commands,
    straight_move,
    written_at,
)
from hardware.machine_types import MachineProfile

PROFILE = MachineProfile(clearance_z=5.0, probe_z_min=-10.0, probe_feed_mm_min=100.0, travel_feed_mm_min=3000.0)


def test_move_words_name_only_the_axes_given() -> None:
    assert axis_words(1.0, None, -2.5) == " X1.0000 Z-2.5000"
    assert straight_move(PROFILE, None, 4.0, None, None) == "G1 Y4.0000 F3000.0"  # the travel feed
    assert straight_move(PROFILE, 1.0, 2.0, 3.0, 600.0) == "G1 X1.0000 Y2.0000 Z3.0000 F600.0"
    with pytest.raises(InvalidConfig) as none:
        axis_words(None, None, None)
    assert none.value.field == "move"


def test_a_probe_down_takes_the_profiles_defaults_and_refuses_a_floor_above_its_start() -> None:
    down = probe_down(PROFILE, 10.0, 20.0, None, None, None)
    assert (down.z_start, down.z_min, down.feed, down.travel) == (5.0, -10.0, 100.0, 3000.0)
    assert down.retract == "G1 Z5.0000 F3000.0"
    assert down.approach_moves((0.0, 0.0, 30.0)) == ["G1 Z5.0000 F3000.0", "G1 X10.0000 Y20.0000 F3000.0"]
    assert down.approach_moves((0.0, 0.0, 5.0)) == ["G1 X10.0000 Y20.0000 F3000.0"]
    assert down.approach_moves((10.0, 20.0, 1.0)) == ["G1 Z5.0000 F3000.0"]
    assert down.approach_moves((10.0, 20.0, 5.0)) == []
    assert written_at((10.0, 20.0, 5.0), 10.00004, None, 5.0) and not written_at((10.0, 20.0, 5.0), None, 20.0001, None)
    with pytest.raises(InvalidConfig) as above:
        probe_down(PROFILE, 0.0, 0.0, 1.0, 1.0, None)
    assert (above.value.field, above.value.value) == ("z_min", 1.0)
    missed = probe_missed(down, ": ALARM:5")
    assert missed.message == "probe at (10.000, 20.000) found no surface above z=-10.000: ALARM:5"
    assert missed.value == [10.0, 20.0]


def test_a_probe_toward_reaches_its_start_up_over_and_down() -> None:
    toward = probe_toward(PROFILE, (1.0, 2.0, 3.0), (1.0, 2.0, -4.0), 50.0)
    assert toward.approach(8.0) == ["G1 Z8.0000 F3000.0", "G1 X1.0000 Y2.0000 F3000.0", "G1 Z3.0000 F3000.0"]
    assert toward.approach(0.0)[0] == "G1 Z3.0000 F3000.0"  # never lower than the start on the way
    assert toward.command == "G38.2 X1.0000 Y2.0000 Z-4.0000 F50.0"
    # without the moves that would not move the tool (its target, as written, is where it is)
    assert toward.approach_moves((5.0, 6.0, 8.0)) == toward.approach(8.0)[1:]  # already up
    assert toward.approach_moves((1.0, 2.0, 8.0)) == ["G1 Z3.0000 F3000.0"]
    assert toward.approach_moves((5.0, 6.0, 3.0)) == ["G1 X1.0000 Y2.0000 F3000.0"]
    assert toward.approach_moves((5.0, 6.0, 0.0)) == ["G1 Z3.0000 F3000.0", "G1 X1.0000 Y2.0000 F3000.0"]
    assert toward.approach_moves((1.0, 2.00004, 3.0)) == ["G1 X1.0000 Y2.0000 F3000.0"]  # 0.04 um away
    assert toward.approach_moves((1.0, 2.0, 3.0)) == []
    odd = probe_toward(PROFILE, (1.0, 2.0, 3.00004), (1.0, 2.0, -4.0), 50.0)
    assert odd.approach_moves((1.0, 2.0, 3.0)) == []  # "Z3.0000" is where the tool is
    assert odd.approach_moves((1.0, 2.0, 1.0)) == ["G1 Z3.0000 F3000.0"]  # up once, not again down
    assert toward.back == "G1 X1.0000 Y2.0000 Z3.0000 F3000.0"
    assert probe_missed(toward).message == "probe from [1.0, 2.0, 3.0] toward [1.0, 2.0, -4.0] touched nothing"


@pytest.mark.parametrize(("start", "target", "feed", "field"), [
    ((0.0, 0.0, math.nan), (0.0, 0.0, 0.0), None, "start"),
    ((0.0, 0.0), (0.0, 0.0, 0.0), None, "start"),
    ((0.0, 0.0, 1.0), ("a", 0.0, 0.0), None, "target"),
    ((0.0, 0.0, 1.0), (0.0, 0.0, 1.0), None, "target"),
    ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), -5.0, "feed_mm_min"),
])
def test_a_probe_toward_refuses_what_is_not_a_probe(start, target, feed, field) -> None:
    with pytest.raises(InvalidConfig) as bad:
        probe_toward(PROFILE, start, target, feed)
    assert bad.value.field == field


def test_tools_and_start_lines_outside_their_range_are_refused() -> None:
    assert check_tool(7, 99) == 7
    for tool in (-1, 100, True, 2.0):
        with pytest.raises(InvalidConfig) as bad:
            check_tool(tool, 99)  # type: ignore[arg-type]
        assert bad.value.field == "tool" and "0..99" in bad.value.message
    assert program_commands(["G21 ; mm", "", "G1 X1"], 2) == ["G21", "G1 X1"]
    with pytest.raises(InvalidConfig) as late:
        program_commands(["G21", "G1 X1"], 3)
    assert (late.value.field, late.value.value) == ("start_line", 3)


@pytest.mark.parametrize("machine", [SerialMachine("mock://args-shared", "grbl", PROFILE),
                                     LinuxCNCMachine("linuxcnc://127.0.0.1:5007", PROFILE)],
                         ids=["serial", "linuxcnc"])
def test_both_backends_refuse_bad_arguments_before_they_need_a_link(machine) -> None:
    """Disconnected: a bad argument is the argument's InvalidConfig, not 'not connected'."""
    calls = [(lambda: machine.probe(0.0, 0.0, z_start=1.0, z_min=2.0), "z_min"),
             (lambda: machine.probe_toward((0.0, 0.0, math.inf), (0.0, 0.0, 0.0)), "start"),
             (lambda: machine.probe_toward((1.0, 1.0, 1.0), (1.0, 1.0, 1.0)), "target"),
             (lambda: machine.select_tool(-1), "tool"),
             (lambda: machine.move(), "move"),
             (lambda: machine.stream(["G1 X1"], start_line=2), "start_line")]
    for call, field in calls:
        with pytest.raises(InvalidConfig) as bad:
            call()
        assert bad.value.field == field
