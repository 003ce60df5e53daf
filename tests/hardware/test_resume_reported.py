"""Resuming after a controller RESET from the last real position reported while streaming.

A reset zeroes the controller's position, and ``ok`` means *planned*: without more, up to a
planner's worth of moves may run twice (the planner bound).  While a program streams, the
host now asks where the tool really is ten times a second (grbl ``?``; Marlin ``S000``,
REALTIME_REPORTING_COMMANDS) and, after a reset, resumes at the command the last report
places the tool in.  The mock's firmware reports where the tool is inside the moving block
at the moment it is asked, and a reset keeps only the commands whose motion completed: the
truth these tests compare with.  A reset is pressed at several moments of a program of many
short moves and of one of a few long moves; each time the executed stream is the program
with at most the stated bound repeated (lines and mm), nothing skipped, and strictly fewer
repeats than the planner bound.
"""

from __future__ import annotations

import math
import threading
import time

import pytest

from hardware.errors import LinkError
from hardware.events import PositionReport
from hardware.machine import Machine, MachineProfile
from hardware.machine_types import ReportEvidence
from hardware.protocol import normalized_commands
from hardware.reports import PositionMark
from hardware.resume import ResumeLocation, command_feeds, end_positions, locate_by_report
from tests.helpers.machines import executed_before_the_cut, reset_in_stream

PROFILES = {"marlin": MachineProfile(), "grbl": MachineProfile(dispense_on="M8", dispense_off="M9")}
SYNC = {"marlin": "M400", "grbl": "G4 P0"}  # the program ends when its motion has ended


def short_moves(dialect: str, moves: int = 40) -> list[str]:
    """0.58 mm moves at 10 mm/s (58 ms each), x always increasing: no place is visited twice."""
    on, off = PROFILES[dialect].dispense_on, PROFILES[dialect].dispense_off
    lines = ["G21", "G90", "G1 X0 Y0 Z1 F600"]
    for i in range(1, moves + 1):
        lines.append(f"G1 X{i * 0.5:.1f} Y{0.3 * (i % 2):.1f}")
        if i % 10 == 3:
            lines.append(on)
        elif i % 10 == 8:
            lines.append(off)
    return lines + [SYNC[dialect]]


def long_moves(dialect: str) -> list[str]:
    """Five 6-8 mm moves at 20 mm/s (0.3-0.4 s each), an open spiral."""
    return ["G21", "G90", "G1 X0 Y0 Z1 F1200", "G1 X8 Y0", "G1 X8 Y8", "G1 X0 Y8", "G1 X0 Y2",
            "G1 X6 Y2", SYNC[dialect]]


def machine(url: str, dialect: str) -> Machine:
    return Machine(url, dialect, PROFILES[dialect], timeout_s=10, boot_wait_s=0.5, boot_quiet_s=0.01, poke_s=0.5)


def path_mm(ends, start: int, ran: int, where) -> float:
    """Length of the program's path from the start point of command ``start`` to ``where``
    inside command ``ran`` (what really ran twice)."""
    total, cursor = 0.0, ends[start - 1]
    for k in range(start, ran):
        total += math.dist(cursor, ends[k])
        cursor = ends[k]
    return total + math.dist(cursor, where)


def reset_and_resume(make_world, dialect: str, lines: list[str], reset_after_s: float, **world):
    url, w = make_world(dialect=dialect, time_scale=1.0, boot_s=0.05, **world)
    m = machine(url, dialect)
    m.connect()
    if dialect == "marlin":
        m.home()
    w.transcript.reset()
    truth: dict = {}
    with reset_in_stream(m, reset_after_s, lambda: truth.setdefault("where", w.reset_controller())), \
            pytest.raises(LinkError):
        m.stream(lines)
    m.connect()
    ran, safe, reconnect = executed_before_the_cut(w, m)  # commands whose motion completed before the reset
    bound = m.resume_line()
    found = m.locate_resume()
    assert m.last_resume == found
    if dialect == "marlin":
        m.home()
    report = m.stream(lines, start_line=found.start)
    assert report.executed == report.total == len(lines)
    commands = normalized_commands(lines)
    home = ["G28"] if dialect == "marlin" else []  # grbl: the reset board needs no homing here (homing off)
    executed = list(w.transcript.commands)
    m.disconnect()
    expected = safe + commands[:ran] + reconnect + home + m.last_preamble + commands[found.start:]
    return found, bound, ran, truth["where"], executed, expected, commands


def check(found, bound, ran, where, executed, expected, commands, profile):
    assert found.basis == "reported position", found
    assert found.start <= ran, found  # nothing skipped
    assert ran - found.start < found.repeat_bound_lines, (ran, found)  # at most the stated bound runs twice
    ends = end_positions(commands, profile.dispense_on, profile.dispense_off)
    assert path_mm(ends, found.start, ran, where) <= found.repeat_bound_mm + 0.01, (where, found)
    assert ran - found.start < ran - bound, (found.start, bound)  # strictly fewer repeats than the planner bound
    assert executed == expected


@pytest.mark.parametrize("dialect", ["grbl", "marlin"])
@pytest.mark.parametrize("reset_after_s", [0.7, 1.5])
def test_a_reset_during_many_short_moves_repeats_at_most_the_stated_bound(make_world, dialect, reset_after_s):
    outcome = reset_and_resume(make_world, dialect, short_moves(dialect), reset_after_s,
                               realtime_reports=dialect == "marlin")
    check(*outcome, PROFILES[dialect])


@pytest.mark.parametrize("dialect", ["grbl", "marlin"])
@pytest.mark.parametrize("reset_after_s", [0.55, 1.15])
def test_a_reset_during_a_long_move_repeats_only_that_move(make_world, dialect, reset_after_s):
    found, *rest = reset_and_resume(make_world, dialect, long_moves(dialect), reset_after_s,
                                    realtime_reports=dialect == "marlin")
    check(found, *rest, PROFILES[dialect])
    assert found.repeat_bound_lines <= 2  # the move in progress, and the next one at most


def test_marlin_without_realtime_reports_keeps_the_planner_bound(make_world):
    """Marlin's default build answers ``S000`` with ``Unknown command``: nothing reports the
    real position while streaming (M154 and plain M114 print the *planned* one), so the
    planner bound stands and says why."""
    found, bound, ran, _, executed, expected, _ = reset_and_resume(make_world, "marlin", short_moves("marlin"), 1.0)
    assert found.basis == "planner bound" and "origin" in found.detail and found.start == bound <= ran
    assert executed == expected


def test_the_connect_probe_finds_realtime_reports_only_where_the_firmware_has_them(make_world):
    for enabled in (True, False):
        url, _ = make_world(dialect="marlin", realtime_reports=enabled)
        m = machine(url, "marlin")
        identity = m.connect()
        assert identity.capabilities["REALTIME_REPORTING_COMMANDS"] is enabled
        assert m.link.realtime_reports is enabled
        m.home()  # the probe's plain ok did not shift any later answer
        assert m.position() == (0.0, 0.0, 0.0)
        m.disconnect()


@pytest.mark.parametrize("dialect", ["grbl", "marlin"])
def test_reports_never_follow_or_delay_an_emergency_stop(make_world, dialect):
    """Reports are asked for by the reader thread under the link's lock, and refused once the
    link is terminal: the wire still ends at the stop byte, and the stop is written at once."""
    url, w = make_world(dialect=dialect, time_scale=1.0, boot_s=0.05, realtime_reports=True)
    m = machine(url, dialect)
    m.connect()
    wire: list[bytes] = []
    port, write = m.link.port, m.link.port.write
    port.write = lambda data: (wire.append(bytes(data)), write(data))[1]
    errors: list[Exception] = []
    streamer = threading.Thread(target=lambda: _stream_catching(m, short_moves(dialect), errors))
    streamer.start()
    request = b"?" if dialect == "grbl" else b"S000\n"
    deadline = time.monotonic() + 10
    while wire.count(request) < 5:  # reports are flowing while the program streams
        assert time.monotonic() < deadline, wire[-5:]
        time.sleep(0.01)
    started = time.monotonic()
    m.emergency_stop()
    elapsed = time.monotonic() - started
    streamer.join(10)
    time.sleep(0.3)  # three report intervals: none may follow the stop
    stop = b"M112\n" if dialect == "marlin" else b"\x18"
    assert wire[-1] == stop and wire.count(stop) == 1, wire[-4:]
    assert errors and elapsed < 0.25, elapsed
    m.disconnect()


def _stream_catching(m: Machine, lines: list[str], errors: list) -> None:
    try:
        m.stream(lines)
    except Exception as exc:  # the stop ends the stream with FirmwareError
        errors.append(exc)


def test_marlin_auto_report_is_the_planned_position_not_the_real_one(make_world):
    """``M154`` (Cap:AUTOREPORT_POS) prints ``report_current_position_projected`` in Marlin
    2.0.9-2.1.2: during a long move it already shows the move's end, while ``S000`` shows
    where the tool is.  So the host never takes an auto-report as evidence of motion."""
    url, w = make_world(dialect="marlin", time_scale=1.0, realtime_reports=True)
    m = machine(url, "marlin")
    identity = m.connect()
    assert identity.capabilities["AUTOREPORT_POS"] is True
    m.send("M154 S1")
    m.send("G1 X60 F600")  # 6 s; acknowledged once planned

    def planned_end_reported() -> bool:  # an auto-report after the move was planned (one a second)
        return any(isinstance(e, PositionReport) and e.axes["X"] == 60.0 for e in list(m.link.unsolicited))
    deadline = time.monotonic() + 4.0   # the first report (1 s after M154), or the next on a loaded host
    while not planned_end_reported() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert planned_end_reported()   # the planned end while the move runs
    m.link.probe_realtime_reports()
    real = m.link.position_marks[-1].position
    assert 0.5 < real[0] < 58.0  # the tool on its way (10 mm/s): 10-20 mm, or further on a loaded host
    m.send("M154 S0")
    m.disconnect()


# --- the pure locator and the evidence rules ----------------------------------------------------

SQUARE = ["G21", "G90", "G1 X0 Y0 Z0 F600", "G1 X10", "G1 X10 Y10", "G1 X0 Y10"]


@pytest.mark.parametrize(("seconds", "lines", "mm"), [
    (0.5, 1, 4 + 5),     # 10 mm/s for 0.5 s: still inside the move the report was in
    (1.0, 2, 4 + 10),    # 6 mm to its end, then 4 mm of the next move
    (9.0, 3, 4 + 26),    # longer than the path sent: the path up to the last command sent
])
def test_locate_by_report_bounds_what_runs_twice(seconds, lines, mm):
    ends = end_positions(SQUARE)
    found = locate_by_report(ends, command_feeds(SQUARE), (4.0, 0.0, 0.0), 3, 6, seconds)
    assert (found.start, found.bound_lines) == (3, lines) and found.bound_mm == pytest.approx(mm)
    assert found.before_mm == pytest.approx(4.0)


def test_a_rapid_in_the_window_bounds_by_the_path_not_by_time():
    program = SQUARE[:4] + ["G0 X10 Y10", "G1 X0 Y10"]  # G0: the controller's own rate
    found = locate_by_report(end_positions(program), command_feeds(program), (4.0, 0.0, 0.0), 3, 6, 0.1)
    assert found.after_mm is None and found.bound_lines == 3 and found.bound_mm == pytest.approx(30.0)


def test_only_reports_of_this_stream_count_and_an_unknown_opening_is_not_placed(make_world):
    url, _ = make_world(dialect="grbl")
    m = machine(url, "grbl")
    m.connect()
    resumer = m.resumer
    resumer.note_stream_start(5)  # a resumed stream: no origin query
    started = resumer.stream_started
    m.link.position_marks.append(PositionMark((10.0, 0.0, 0.0), 0, started - 1.0, started))
    assert resumer.report_evidence({}, 5, LinkError("gone")) is None  # asked before the stream: stale
    resumer.program = ["G21", "G90", "G1 X10 F600", "G1 Y5", "G1 X0", "G1 Y0"]  # opening from nowhere known
    fallback = ResumeLocation(0, "planner bound", "the controller reports the power-on origin")
    found = resumer.locate_by_report(fallback, ReportEvidence((10.0, 0.0, 0.0), 2, 0.0, 0.5), 6, 6)
    assert found.basis == "planner bound" and "opening" in found.detail
    known_origin = ReportEvidence((10.0, 2.0, 0.0), 2, 0.0, 0.5, origin=(0.0, 0.0, 0.0))
    placed = resumer.locate_by_report(fallback, known_origin, 6, 6)
    assert placed.basis == "reported position" and placed.start == 3  # the origin makes the opening known
    m.disconnect()
