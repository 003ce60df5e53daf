"""Resuming after a controller reset or a dropped link, located by where the tool stands.

``ok`` means *planned*: after a reset the planner bound alone may send up to a planner's
worth of short moves twice.  ``Machine.locate_resume`` asks the controller where the tool
is and finds that place on the program (``hardware.resume.locate_by_position``): when the
link dropped and the controller kept its position (the mock's grbl on a disconnect; Marlin
answers by line numbers), the executed stream is the program exactly once plus the
re-homing and modal replay, for every cut point.  A controller *reset* zeroes the position
(Marlin and grbl, on the mock as on real boards): there the bound stands and says so.
"""

from __future__ import annotations

import pytest

from hardware.errors import LinkError
from hardware.machine import Machine, MachineProfile
from hardware.mock import FaultConfig
from hardware.protocol import normalized_commands
from hardware.resume import end_positions, locate_by_position
from tests.helpers.machines import executed_before_the_cut

PROFILES = {"marlin": MachineProfile(), "grbl": MachineProfile(dispense_on="M8", dispense_off="M9")}


def program(dialect: str, moves: int = 40) -> list[str]:
    """Short moves (0.5 mm in x, a zig-zag in y) that never revisit a place, the dispenser
    switched on and off along the way."""
    on, off = PROFILES[dialect].dispense_on, PROFILES[dialect].dispense_off
    lines = ["G21", "G90", "G1 X0 Y0 Z1 F3000"]
    for i in range(1, moves + 1):
        lines.append(f"G1 X{i * 0.5:.1f} Y{(i * 7) % 11 * 0.3:.1f}")
        if i % 10 == 3:
            lines.append(on)
        elif i % 10 == 8:
            lines.append(off)
    return lines


def machine(url: str, dialect: str) -> Machine:
    return Machine(url, dialect, PROFILES[dialect], timeout_s=10, boot_wait_s=0.5, boot_quiet_s=0.01, poke_s=0.02)


def cut_and_resume(make_world, dialect: str, fault: str, at: int):
    lines = program(dialect)
    # the cut comes at program command ``at``: the controller runs the program's safe_off first
    cut = at + len(PROFILES[dialect].safe_off)
    url, world = make_world(dialect=dialect, faults=FaultConfig(**{fault: cut}), homing=dialect == "grbl")
    m = machine(url, dialect)
    m.connect()
    m.home()
    world.transcript.reset()
    with pytest.raises(LinkError):
        m.stream(lines)
    m.connect()
    ran, safe, reconnect = executed_before_the_cut(world, m)
    bound = m.resume_line()
    found = m.locate_resume()
    assert m.last_resume == found
    m.home()
    report = m.stream(lines, start_line=found.start)
    assert report.executed == report.total == len(lines)
    commands = normalized_commands(lines)
    home = ["G28"] if dialect == "marlin" else []  # grbl's $H is a system command: not in the transcript
    executed = list(world.transcript.commands)
    m.disconnect()   # its safe_off comes after
    assert world.transcript.commands == executed + normalized_commands(m.profile.safe_off)
    return found, bound, ran, executed, safe + commands[:ran] + reconnect + home + m.last_preamble + \
        commands[found.start:]


@pytest.mark.parametrize("at", [4, 9, 17, 26, 38, 47])
def test_grbl_whose_link_dropped_resumes_where_the_tool_stands_exactly_once(make_world, at):
    """The mock's grbl keeps its position when the link drops (as a board that does not reset
    on reconnect does): the resume starts at the first command not completed."""
    found, bound, ran, executed, expected = cut_and_resume(make_world, "grbl", "disconnect_at_line", at)
    assert found.basis == "position" and "stood at" in found.detail, found
    assert found.start == ran >= bound  # not one move repeated, none skipped
    assert executed == expected


@pytest.mark.parametrize("at", [4, 17, 38])
def test_marlin_that_kept_running_resumes_by_line_numbers_exactly(make_world, at):
    found, _, ran, executed, expected = cut_and_resume(make_world, "marlin", "disconnect_at_line", at)
    assert found.basis == "line numbers" and found.start == ran
    assert executed == expected


@pytest.mark.parametrize("dialect", ["marlin", "grbl"])
@pytest.mark.parametrize("at", [9, 26, 47])
def test_a_reset_loses_the_position_and_keeps_the_planner_bound_saying_so(make_world, dialect, at):
    """A controller reset zeroes the position (Marlin and grbl alike, on the mock as on real
    boards).  Marlin's default build reports nothing while streaming: the planner bound
    stands and says why.  grbl's status reports during the stream place the tool
    (``tests/hardware/test_resume_reported.py``), later than the bound or, when the report
    is older than the bound, earlier (a real position is never discarded: resume earlier)."""
    found, bound, ran, executed, expected = cut_and_resume(make_world, dialect, "reset_at_line", at)
    if dialect == "marlin":
        assert found.basis == "planner bound" and "origin" in found.detail and found.start == bound
    else:
        assert found.basis in ("planner bound", "reported position"), found
        assert found.start >= bound or "before the planner bound" in found.detail, found
    assert found.start <= ran and executed == expected  # repeats (at most a planner's worth), never skips


# --- the pure locator ---------------------------------------------------------------------------

PATH = ["G21", "G90", "G1 X0 Y0 Z1 F3000", "G1 X10", "M106", "G1 Y10", "G1 X0", "G1 X10 Y10"]


@pytest.mark.parametrize(("position", "lo", "hi", "start"), [
    ((10, 0, 1), 2, 8, 4),     # at the end of move 3: the dispenser switch after it is sent again ...
    ((10, 5, 1), 2, 8, 5),     # inside move 5: it runs again
    ((0, 0, 1), 3, 8, 3),      # nothing of the window moved yet
    ((5, 10, 1), 2, 8, None),  # on move 6 and on move 7: the path passes twice
    ((10, 10, 1), 2, 8, None),  # the end of move 5 and of move 7
    ((10, 10, 1), 2, 6, 6),    # ... unless move 7 was never sent
    ((3, 3, 1), 2, 8, None),   # nowhere on the path
    ((0, 0, 1), 5, 8, None),   # before the bound: not believable
    ((10, 0, 1), 5, 8, 5),     # where the bound left it: nothing after the bound moved
])
def test_locate_by_position(position, lo, hi, start):
    assert locate_by_position(end_positions(PATH), position, lo, hi) == start


def test_an_acknowledged_command_that_does_not_move_is_not_sent_again():
    ends = end_positions(PATH)
    assert locate_by_position(ends, (10, 0, 1), 2, 8, acked=5) == 5  # ... unless its ok came: it ran
    assert locate_by_position(ends, (10, 0, 1), 2, 8, acked=8) == 5  # never past the next move


def test_end_positions_in_mm_and_unknown_where_the_frame_is():
    ends = end_positions(["G20", "G90", "G1 X1 Y1 Z1", "G91", "G1 X1", "G28", "G90", "G1 X0 Y0 Z0", "G92 X5"])
    assert ends[2] == pytest.approx((25.4, 25.4, 25.4)) and ends[4] == pytest.approx((50.8, 25.4, 25.4))
    assert ends[:2] == [None, None] and ends[5] is None and ends[7] == (0.0, 0.0, 0.0) and ends[8] is None
