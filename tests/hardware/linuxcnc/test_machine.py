"""The LinuxCNC backend against Conforma's three-axis simulator (hardware/linuxcnc/sim/xyz.ini).

Every test checks the controller's own view through an independent linuxcncrsh session
(``observer``), not only what the backend reports."""

from __future__ import annotations

import math
import os
import threading
import time

import numpy as np
import pytest

from hardware.errors import FirmwareError, InvalidConfig, LinkError, MachineStateError, ProbeFailed
from hardware.machine_state import InterruptedProgram
from tests.hardware.linuxcnc.conftest import SURFACE_SLOPE_X, SURFACE_Z, wait_until

# how long a program may take to reach a line: the preamble's MDI, the file's open and run take
# seconds on a loaded host (the programs themselves run a few seconds)
PROGRAM_START_S = 30.0
SQUARE = ["G21 G90 G64 P0.001", "G1 X0 Y0 Z5 F6000"] + [
    f"G1 X{x:.1f} Y{y:.1f} F2400" for _ in range(2) for x, y in ((20, 0), (20, 20), (0, 20), (0, 0))]


def _joints(observer) -> list[float]:
    return [float(v) for v in observer.get("joint_pos").split()[:3]]


def _run_in_thread(machine, lines):
    outcome: dict = {}

    def run() -> None:
        try:
            outcome["report"] = machine.stream(lines)
        except Exception as exc:  # the test inspects it
            outcome["error"] = exc

    thread = threading.Thread(target=run)
    thread.start()
    return thread, outcome



def test_connect_home_and_mdi_moves(machine, lcnc_xyz):
    observer = lcnc_xyz.session()
    assert machine.identity.firmware.startswith("LinuxCNC")
    assert machine.state == "idle"
    assert observer.get("joint_homed").split()[:3] == ["YES"] * 3
    assert observer.get("estop") == "OFF" and observer.get("machine") == "ON"
    assert machine.move(x=12.5, y=-7.25, z=4.0, feed_mm_min=6000) == pytest.approx((12.5, -7.25, 4.0), abs=1e-6)
    assert _joints(observer) == pytest.approx([12.5, -7.25, 4.0], abs=1e-6)
    with pytest.raises(FirmwareError, match="LinuxCNC"):
        machine.send("G1 X")  # the controller's parse error, not a silent success
    assert machine.state == "idle"
    assert machine.move(x=0.0) == pytest.approx((0.0, -7.25, 4.0), abs=1e-6)
    # a move that would change nothing is not sent; after another command (its modal state
    # unknown) or to another place at another feed it is
    seen = machine.console.last_seq
    assert machine.move(x=0.0, z=4.0) == pytest.approx((0.0, -7.25, 4.0), abs=1e-6)
    assert machine.console.since(seen, direction="sent").entries == []
    machine.send("G91")
    assert machine.move(x=0.0) == pytest.approx((0.0, -7.25, 4.0), abs=1e-6)
    assert machine.move(x=0.0, feed_mm_min=600) == pytest.approx((0.0, -7.25, 4.0), abs=1e-6)
    sent = [entry.text for entry in machine.console.since(seen, direction="sent").entries]
    assert sent == ["G91", "G90 G1 X0.0000 F6000.0", "G90 G1 X0.0000 F600.0"], sent


def test_probe_cycle_reads_the_trip_point(machine, lcnc_xyz):
    observer = lcnc_xyz.session()
    for x, y, z_start in ((10.0, 5.0, -1.0), (-40.0, 12.0, -1.5)):
        touch = machine.probe(x, y, z_start=z_start, z_min=-10.0, feed_mm_min=100.0)
        surface = SURFACE_Z + SURFACE_SLOPE_X * x
        assert (touch.x, touch.y) == pytest.approx((x, y), abs=1e-6)
        assert touch.z == pytest.approx(surface, abs=0.005)  # 100 mm/min: 1.7 um per servo period
        # retracted: linuxcncrsh's "wait done" can answer a servo period or two before the
        # joints' feedback settles on a loaded host (seen: 0.95 um short), so allow it 2 s
        assert wait_until(lambda z=z_start: _joints(observer)[2] == pytest.approx(z, abs=1e-6), 2.0), _joints(observer)
    with pytest.raises(ProbeFailed):
        machine.probe(0.0, 0.0, z_start=-0.5, z_min=-1.5)  # the surface is at z = -2 there
    assert machine.state == "idle"
    assert wait_until(lambda: _joints(observer) == pytest.approx([0.0, 0.0, -0.5], abs=1e-6), 2.0), _joints(observer)


def test_stream_10000_lines_runs_to_the_last_point(machine, lcnc_xyz):
    observer = lcnc_xyz.session()
    n, r = 10_000, 50.0
    points = [(r * math.cos(2 * math.pi * k / n) - r, r * math.sin(2 * math.pi * k / n)) for k in range(1, n + 1)]
    lines = ["G21 G90 G64 P0.01 Q0.01", "G1 X0 Y0 Z1 F6000"] + [f"G1 X{x:.4f} Y{y:.4f}" for x, y in points[:-1]]
    lines.append("G1 X-3.0000 Y0.0000 Z2.0000")
    seen: list[int] = []
    report = machine.stream(lines, on_progress=lambda done, total: seen.append(done))
    assert report.total == len(lines) == 10_002 and report.executed == report.total
    assert not report.cancelled
    assert seen == sorted(seen) and seen[-1] == report.total and len(set(seen)) > 3
    assert _joints(observer) == pytest.approx([-3.0, 0.0, 2.0], abs=1e-6)
    assert observer.get("program_status") == "IDLE" and observer.pop_error() is None
    assert machine.state == "idle"


def test_every_hal_watch_sample_is_one_moment_of_all_its_pins(machine, lcnc_xyz):
    """``HalWatch`` reads its pins one after another.  Along a straight move every sample
    must lie on the line: a pass of reads the host paused between X and Z while the servo
    thread moved on would pair one period's X with a later period's Z (8 um off the line per
    period at this feed); the watcher prints a pass only when a second pass agreed."""
    names = ["joint.0.motor-pos-fb", "joint.1.motor-pos-fb", "joint.2.motor-pos-fb"]
    line = ["G1 X40 Y28 Z25 F1200", "G1 X10 Y10 Z10 F1200"]   # y = 0.6 x + 4, z = 0.5 x + 5
    with lcnc_xyz.watch(names) as watch:
        machine.stream(["G21 G90 G61", "G1 X10 Y10 Z10 F6000", *line, *line, "G64"])  # G61: no corner blends
    xyz = np.array([values for _, values in watch.samples])
    on_line = xyz[(xyz[:, 0] > 10.01) & (xyz[:, 0] < 39.99)]  # the approach from home ends at x = 10
    assert len(on_line) > 1000, len(on_line)
    for k, slope in ((1, 0.6), (2, 0.5)):  # the same offset for every sample: where homing latched
        off_line = on_line[:, k] - slope * on_line[:, 0]
        assert np.ptp(off_line) < 1e-4, (k, np.ptp(off_line))


def test_pause_holds_and_resume_finishes(machine, lcnc_xyz):
    observer = lcnc_xyz.session()
    thread, outcome = _run_in_thread(machine, SQUARE)
    assert wait_until(lambda: machine.state == "printing" and machine.progress[0] >= 3, timeout_s=PROGRAM_START_S)
    machine.pause()
    assert wait_until(lambda: observer.get("program_status") == "PAUSED")
    held = _joints(observer)
    time.sleep(0.3)
    assert _joints(observer) == pytest.approx(held, abs=1e-9) and machine.state == "paused"
    machine.resume()
    thread.join(30)
    assert "error" not in outcome and outcome["report"].executed == len(SQUARE)
    assert _joints(observer) == pytest.approx([0.0, 0.0, 5.0], abs=1e-6)


def test_cancel_aborts_the_program(machine, lcnc_xyz):
    observer = lcnc_xyz.session()
    thread, outcome = _run_in_thread(machine, SQUARE)
    assert wait_until(lambda: machine.state == "printing" and machine.progress[0] >= 3, timeout_s=PROGRAM_START_S)
    machine.cancel()
    thread.join(10)
    report = outcome["report"]
    assert report.cancelled and 3 <= report.executed < report.total
    assert wait_until(lambda: observer.get("program_status") == "IDLE")
    stopped = _joints(observer)
    time.sleep(0.2)
    assert _joints(observer) == pytest.approx(stopped, abs=1e-9)  # nothing moves after abort
    assert machine.state == "idle"


ESTOP_STATE = 1  # linuxcnc.STATE_ESTOP: the controller's task state while in e-stop
# watched at the controller (HAL, hardware.linuxcnc.HalWatch): the state the controller
# reports, its e-stop output (what a machine's e-stop chain / amplifier enable follows) and
# the motion controller's enable
ESTOP_SIGNALS = {"reported": ("task_state", lambda v: v == ESTOP_STATE),
                 "output": ("iocontrol.0.user-enable-out", lambda v: v == 0),
                 "motion": ("motion.motion-enabled", lambda v: v == 0)}


def measure_estops(machine, sim, n: int) -> dict[str, list[float]]:
    """Emergency-stop ``n`` times, each while a program runs.  Per stop, milliseconds from
    the operator's stop (the call to ``emergency_stop``) until the controller itself shows
    it, sampled from HAL every 0.5 ms on the host's monotonic clock (a sampling delay only
    makes a figure larger).  Also checks, every time, that the program ended with the stop,
    nothing moves afterwards and nothing is sent until reconnected."""
    observer = sim.session()
    names = [name for name, _ in ESTOP_SIGNALS.values()]
    figures: dict[str, list[float]] = {key: [] for key in (*ESTOP_SIGNALS, "call")}
    try:
        for _ in range(n):
            if "NO" in observer.get("joint_homed").upper().split()[:3]:
                machine.home()
            with sim.watch(names) as watch:
                thread, outcome = _run_in_thread(machine, SQUARE)
                assert wait_until(lambda: machine.state == "printing" and machine.progress[0] >= 3,
                                  timeout_s=PROGRAM_START_S)
                issued = time.monotonic_ns()
                machine.emergency_stop()
                figures["call"].append((time.monotonic_ns() - issued) / 1e6)
                seen: dict[str, int | None] = {key: None for key in ESTOP_SIGNALS}
                assert wait_until(lambda seen=seen, watch=watch, issued=issued: _all_seen(seen, watch, issued),
                                 timeout_s=5.0), (seen, watch.ended(), f"get estop: {observer.get('estop')}")
            for key, t_ns in seen.items():
                figures[key].append((t_ns - issued) / 1e6)
            thread.join(10)
            assert isinstance(outcome.get("error"), FirmwareError)  # the program ended with the stop
            assert machine.state == "error" and observer.get("estop") == "ON"
            frozen = _joints(observer)
            time.sleep(0.1)
            assert _joints(observer) == pytest.approx(frozen, abs=1e-9)
            with pytest.raises(MachineStateError):  # nothing is sent until reconnected
                machine.move(x=1.0)
            machine.connect()
            assert observer.get("estop") == "OFF" and machine.state == "idle"
    finally:
        observer.close()
    return figures


def _all_seen(seen: dict, watch, issued: int) -> bool:
    """Fill in the first time each e-stop signal showed the stop (at or after ``issued``)."""
    for key, (name, test) in ESTOP_SIGNALS.items():
        seen[key] = seen[key] or watch.first(name, test, issued)
    return all(seen.values())


def estop_summary(figures: dict[str, list[float]]) -> str:
    import numpy as np

    rows = []
    for key, values in figures.items():
        v = np.array(values)
        rows.append(f"  {key:9s} min {v.min():6.1f}  median {np.median(v):6.1f}  p95 {np.percentile(v, 95):6.1f}  "
                    f"max {v.max():6.1f} ms  all: {' '.join(f'{x:.0f}' for x in values)}")
    return "\n".join(rows)


ESTOP_STOPS = 10
ESTOP_BOUND_MS = 2000.0  # every stop, whatever the box's load (see check_estop_figures)
ESTOP_MEDIAN_MS = 100.0
# the 100 ms median holds where the simulator's processes get a core within a few ms: judged
# while the box's load average is at most this many runnable processes per core
ESTOP_JUDGED_LOAD_PER_CORE = 4.0


def check_estop_figures(figures: dict[str, list[float]], *, p95: bool = False,
                        load_per_core: float = 0.0) -> None:
    """What is asserted about a series of stops (``figures``: ms per stop, from the call):

    * every stop reaches the controller: its e-stop output (``iocontrol.0.user-enable-out``,
      what the machine's e-stop chain and amplifier enables follow), its motion enable and
      the state its task reports (``get estop``, every GUI) all show it within 2 s, at any load;
    * the e-stop output and the motion enable drop within 100 ms in the median, and, with
      ``p95`` (the bench's 30 stops), at the 95th percentile -- judged while
      ``load_per_core`` (the load average over the stops per core, measured by the caller)
      is at most ``ESTOP_JUDGED_LOAD_PER_CORE``.

    Why conditional: the simulator's processes (linuxcncrsh, the task, iocontrol) are
    ordinary user processes on a 2-core box shared with other suites, with no real-time
    kernel, and the stop crosses all three.  A quiet stop takes 20-30 ms to the output and
    60-75 ms to the reported state; at load 17 (8.5 per core) 1-3 stops of 10 waited for a
    core, 120-900 ms, and at load 25 beside another suite's Chromium (which raises its own
    priority, nice -8) half of them did (median 103 ms).  That is the box's scheduling, not
    the stop's path; the 2 s bound is what the host promises at any load.  The task's
    reported state is printed, not held to 100 ms: it trails the output by 35-45 ms even when
    quiet."""
    import numpy as np

    for key in ("output", "motion", "reported"):
        assert max(figures[key]) < ESTOP_BOUND_MS, (key, figures[key])
    if load_per_core > ESTOP_JUDGED_LOAD_PER_CORE:
        print(f"e-stop medians not judged: load {load_per_core:.1f} per core > {ESTOP_JUDGED_LOAD_PER_CORE}")
        return
    for key in ("output", "motion"):
        assert np.median(figures[key]) < ESTOP_MEDIAN_MS, (key, figures[key])
        if p95:
            assert np.percentile(figures[key], 95) < ESTOP_MEDIAN_MS, (key, figures[key])


def load_per_core() -> float:
    """The 1-minute load average per core."""
    return os.getloadavg()[0] / (os.cpu_count() or 1)


def test_every_emergency_stop_reaches_the_controller(machine, lcnc_xyz):
    """10 stops, each while a program runs, every one timed at the controller (HAL, sampled
    every 0.5 ms), not by our bookkeeping; see :func:`check_estop_figures`.  ``make bench``
    (tests/bench/test_bench_linuxcnc_estop.py) runs 30 and holds the p95 to 100 ms."""
    figures = measure_estops(machine, lcnc_xyz, ESTOP_STOPS)
    load = load_per_core()
    print(f"e-stop, {ESTOP_STOPS} stops while a program runs, ms from the call (load {load:.1f} per core):\n"
          f"{estop_summary(figures)}")
    check_estop_figures(figures, load_per_core=load)


def test_lost_connection_aborts_and_resumes(machine, lcnc_xyz):
    observer = lcnc_xyz.session()
    thread, outcome = _run_in_thread(machine, SQUARE)
    assert wait_until(lambda: machine.state == "printing" and machine.progress[0] >= 4, timeout_s=PROGRAM_START_S)
    machine.link.sever()
    thread.join(10)
    assert isinstance(outcome.get("error"), LinkError)
    assert machine.link_lost and machine.state == "error"
    # the stop session aborted the program: it does not run on unsupervised
    assert wait_until(lambda: observer.get("program_status") == "IDLE")
    stopped = _joints(observer)
    time.sleep(0.2)
    assert _joints(observer) == pytest.approx(stopped, abs=1e-9)
    with pytest.raises(MachineStateError):
        machine.move(x=1.0)
    machine.connect()
    start = machine.resume_line()
    assert 4 <= start < len(SQUARE)
    report = machine.stream(SQUARE, start_line=start)
    assert report.executed == len(SQUARE) and report.start_line == start
    assert _joints(observer) == pytest.approx([0.0, 0.0, 5.0], abs=1e-6)


def _square_ends() -> list[tuple[float, float, float] | None]:
    """Where each SQUARE command leaves the tool (mm; None: no motion), worked out by hand."""
    corners = [(x, y, 5.0) for _ in range(2) for x, y in ((20, 0), (20, 20), (0, 20), (0, 0))]
    return [None, (0.0, 0.0, 5.0), *corners]


def _distance_to_segment(p, a, b) -> float:
    ab, ap = [bj - aj for aj, bj in zip(a, b, strict=True)], [pj - aj for aj, pj in zip(a, p, strict=True)]
    t = max(0.0, min(1.0, sum(u * v for u, v in zip(ab, ap, strict=True)) / max(sum(u * u for u in ab), 1e-12)))
    return math.dist(p, [aj + t * u for aj, u in zip(a, ab, strict=True)])


def test_a_lost_program_is_recorded_as_the_controller_ran_it_and_resumed_from_that_record(machine, lcnc_xyz):
    """Held by a pause at a line the controller reports, then the link drops: the machine
    records the program in the record type the serial backend keeps, with what LinuxCNC
    told (the commands before the line in motion, the file it ran), which the held tool
    confirms by geometry; its status shows it; the reconnect's resume starts there and the
    square ends where it ends uninterrupted."""
    observer = lcnc_xyz.session()
    thread, outcome = _run_in_thread(machine, SQUARE)
    assert wait_until(lambda: machine.state == "printing" and machine.progress[0] >= 4, timeout_s=PROGRAM_START_S)
    machine.pause()
    assert wait_until(lambda: observer.get("program_status") == "PAUSED")
    line = int(float(observer.get("program_line")))  # the file's line in motion (a fresh start: no preamble)
    assert wait_until(lambda: machine.progress[0] == line - 1)  # the machine's poll has seen it
    held = _joints(observer)
    machine.link.sever()
    thread.join(10)
    assert isinstance(outcome.get("error"), LinkError) and outcome["error"].resume_line == line - 1
    gap = machine.interrupted_program
    assert isinstance(gap, InterruptedProgram) and gap is machine.machine_state.interrupted
    assert (gap.total, gap.acked_index, gap.moved_index) == (len(SQUARE), line - 1, line - 1)
    assert (gap.acked_line_no, gap.inflight, gap.reset, gap.report) == (None, [], False, None)
    with open(gap.program_file, encoding="utf-8") as program:  # what the controller ran
        assert program.read().splitlines() == [*SQUARE, "M2"]
    # the tool held on the move of command line - 1: every command before it had finished
    ends = _square_ends()
    assert 5 <= line <= len(SQUARE)  # command line - 1 >= 4: an edge of the square after its first
    assert _distance_to_segment(held, ends[line - 2], ends[line - 1]) < 0.01, (line, held)
    assert machine.status()["program"] == {"state": "interrupted", "line": line - 1, "total": len(SQUARE),
                                           "resume_line": line - 1}
    machine.connect()
    assert machine.resume_line() == gap.acked_index
    report = machine.stream(SQUARE, start_line=gap.acked_index)
    assert report.executed == len(SQUARE) and report.start_line == line - 1
    assert machine.interrupted_program is None and machine.status()["program"] is None
    assert _joints(observer) == pytest.approx([0.0, 0.0, 5.0], abs=1e-6)


def test_probe_toward_and_select_tool(machine, lcnc_xyz):
    """G38.2 toward any point (here down and sideways onto the plane z = -2 + 0.01 x) and
    T<n> M6: the calibration jobs' host calls."""
    observer = lcnc_xyz.session()
    start, target = (10.0, 5.0, -1.0), (14.0, 5.0, -9.0)  # x = 10 + (z_start - z) / 2 on the way
    touch = machine.probe_toward(start, target, feed_mm_min=100.0)
    # on the line: x = 10 + (-1 - z) / 2; on the plane: z = -2 + 0.01 x  => z = -1.8955, x = 10.4478
    z = (-2 + 0.095) / 1.005
    assert touch.z == pytest.approx(z, abs=0.005) and touch.x == pytest.approx(10 + (-1 - touch.z) / 2, abs=1e-4)
    assert touch.y == pytest.approx(5.0, abs=1e-6)
    assert _joints(observer) == pytest.approx(list(start), abs=1e-6)  # back at the start
    seen = machine.console.last_seq  # again from there: no move of nothing is sent
    again = machine.probe_toward(start, target, feed_mm_min=100.0)
    sent = [entry.text for entry in machine.console.since(seen, direction="sent").entries]
    assert len(sent) == 3 and sent[0].startswith("G90 G38.2 ") and sent[1].startswith("(DEBUG,"), sent
    assert sent[2] == "G90 G1 X10.0000 Y5.0000 Z-1.0000 F6000.0", sent  # straight back
    assert again.z == pytest.approx(touch.z, abs=0.005)
    with pytest.raises(ProbeFailed):
        machine.probe_toward((0.0, 0.0, -0.5), (0.0, 0.0, -1.5))
    assert _joints(observer) == pytest.approx([0.0, 0.0, -0.5], abs=1e-6)
    machine.select_tool(2)
    assert observer.get("tool").split()[-1] == "2"
    with pytest.raises(InvalidConfig):
        machine.select_tool(True)
    assert machine.state == "idle"


# F40 (16.9 mm/s): 4.8 in of moves take 7.2 s, long enough for the program's polling loop to report
# it mid-way on a loaded host (at F120, 2.4 s, the first progress report can come at the end)
INCH_RELATIVE = ["G20 G90 G64 P0.0001", "G1 X0 Y0 Z0.2 F40", "G91"] + [
    f"G1 X{dx:.2f} Y{dy:.2f}" for _ in range(2) for dx, dy in ((0.8, 0), (0, 0.8), (-0.4, 0), (0, -0.4))]


def test_a_resumed_program_replays_its_modal_state(machine, lcnc_xyz):
    """Inches, relative moves and a feed set once: interrupted, then the operator's MDI in
    mm / absolute, then resumed; it ends where the uninterrupted program ends."""
    observer = lcnc_xyz.session()
    machine.stream(INCH_RELATIVE)
    uninterrupted = _joints(observer)
    machine.send("G21 G90")
    machine.move(x=0, y=0, z=5)
    seen: list[tuple[int, int]] = []

    def cut_after_five(executed: int, total: int) -> None:  # in the program's own polling loop
        seen.append((executed, total))
        if 5 <= executed < total and len([e for e, _ in seen if e >= 5]) == 1:
            machine.link.sever()

    try:
        machine.stream(INCH_RELATIVE, on_progress=cut_after_five)
    except LinkError:
        pass
    else:
        pytest.fail(f"the program ran to its end, the link never cut; progress seen: {seen}")
    machine.connect()
    start = machine.resume_line()
    machine.send("G21 G90 G1 F6000")  # the operator leaves mm / absolute / another feed
    machine.move(z=10.0)
    report = machine.stream(INCH_RELATIVE, start_line=start)
    assert 3 <= start < len(INCH_RELATIVE) and report.executed == len(INCH_RELATIVE)
    assert machine.last_preamble[:2] == ["M65 P0", "G20"] and "G91" in machine.last_preamble
    assert _joints(observer) == pytest.approx(uninterrupted, abs=1e-6)
