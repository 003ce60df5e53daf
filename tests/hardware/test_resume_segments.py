"""Resume after controller resets never skips a move, with grbl's real buffers on the mock.

grbl 1.1 acknowledges a line once its motion is *planned*; the planner holds ``[OPT:V,15,..]``
blocks, and the stepper releases a block from the planner as soon as it has prepared all of
its 10 ms step segments (SEGMENT_BUFFER_SIZE 6 on the 328P), before they move.  So up to 15
blocks plus a segment buffer of short moves are acknowledged and unmoved when the board
resets.  The mock's grbl models that buffer: a bound of 15 alone skips moves on it, as it did
on the real firmware; the machine's bound (planner plus stepper, per dialect) and the last
reported position never do, and the resume states how many commands may run again.
"""

from __future__ import annotations

import random
import threading
import time

import pytest

from hardware.dialects import GRBL
from hardware.errors import LinkError, MachineStateError
from hardware.machine import Machine, MachineProfile
from hardware.protocol import normalized_commands
from hardware.resume import ResumeLocation, executed_bound, modal_preamble, planner_blocks
from tests.helpers.machines import executed_before_the_cut, reset_in_stream

PROFILE = MachineProfile(dispense_on="M8", dispense_off="M9")
RESET_TIMES: list[float] = []  # when the tests reset the controller (Unix time, s)


def short_moves(count: int) -> list[str]:
    """0.08 mm moves at 10 mm/s (8 ms each: one step segment apiece), x always increasing,
    so no place of the path is visited twice and every segment slot holds another block."""
    moves = [f"G1 X{i * 0.08:.2f} Y{0.05 * (i % 2):.2f}" for i in range(1, count + 1)]
    return ["G21", "G90", "G1 X0 Y0 Z1 F600", *moves, "G4 P0"]


def grbl(make_world, time_scale: float = 1.0) -> tuple[Machine, object]:
    url, world = make_world(dialect="grbl", time_scale=time_scale, boot_s=0.02)
    m = Machine(url, "grbl", PROFILE, timeout_s=10, boot_wait_s=0.5, boot_quiet_s=0.01, poke_s=0.5)
    m.connect()
    world.transcript.reset()
    return m, world


def reset_now(world) -> None:
    """The controller resets now; the moment goes to ``RESET_TIMES``."""
    RESET_TIMES.append(time.time())
    world.reset_controller()


def stream_until_reset(m: Machine, world, lines: list[str], start: int, after_s: float) -> bool:
    """Stream from ``start``; the controller resets ``after_s`` after the stream holds the
    machine (:func:`tests.helpers.machines.reset_in_stream`: a reset landing before the claim
    is one the machine rightly refuses to stream after,
    ``test_a_reset_before_the_stream_claims_refuses_it``).  False when the program ended first."""
    with reset_in_stream(m, after_s, lambda: reset_now(world)):
        try:
            m.stream(lines, start_line=start)
        except LinkError:
            return True
        except MachineStateError as exc:  # the link failed before the stream began: say how
            raise AssertionError(f"{exc}; {wire_story(m, world)}") from exc
    return False


def wire_story(m: Machine, world) -> str:
    """What a failure message needs to tell a late reset from a lost answer: the link's
    failure, the controller's last commands and faults, the resets and the last lines."""
    fatal = m.link.session.fatal if m.link is not None else None
    now = time.time()
    wire = [(round(e.t - now, 3), e.direction, e.text) for e in m.console.since(m.console.last_seq - 30).entries]
    return (f"the link's failure: {fatal!r}; the controller ran {world.transcript.commands[-5:]}; faults "
            f"{world.stats.faults}; resets (s ago) {[round(t - now, 3) for t in RESET_TIMES[-2:]]}; the wire (s ago): "
            f"{wire}")


def reset_when_held(world, held: int, limit_s: float = 5.0) -> threading.Thread:
    """A thread that resets the controller as soon as its planner holds ``held`` blocks
    (the mock's truth: acknowledged, planned and not finished *now*).  The count and the reset
    happen under the world's lock at one instant: the planner's list keeps a finished block
    until the mock's own thread next runs, so on a busy host its length alone counts blocks
    that ended before the reset lands."""
    def watch() -> None:
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            with world.cond:
                firmware = world.firmware
                now = time.monotonic()
                if firmware is not None and sum(end > now for end in firmware.planner) >= held:
                    reset_now(world)
                    return
            time.sleep(0.0005)
    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


def test_the_mock_holds_a_segment_buffer_beyond_the_planner(make_world):
    """A reset in a stream of short moves while more than the 15 planner blocks are held
    (the rest released into the segment buffer): the planner-only bound would skip moves;
    the machine's bound (planner plus stepper) does not."""
    m, world = grbl(make_world)
    lines = short_moves(400)
    commands = normalized_commands(lines)
    assert m.planner_blocks == 15 and m.held_moves == 15 + GRBL.stepper_queue
    watcher = reset_when_held(world, 18)
    with pytest.raises(LinkError):
        m.stream(lines)
    watcher.join()
    m.connect()
    gap = m.interrupted_program
    ran, _, _ = executed_before_the_cut(world, m)  # the commands whose motion completed
    blocks = planner_blocks(commands, PROFILE.dispense_on, PROFILE.dispense_off)
    assert gap.acked_index - ran > 15, wire_story(m, world)  # acknowledged and never moved: planner + segments
    assert executed_bound(blocks, gap.acked_index, 15) > ran  # the planner alone would skip
    assert m.resume_line() <= ran  # planner + stepper: none skipped
    m.disconnect()


def test_twenty_resets_at_random_moments_skip_nothing_and_state_the_repeats(make_world):
    m, world = grbl(make_world)  # real time: the reported position's bound is in real seconds
    lines = short_moves(120)
    commands = normalized_commands(lines)
    p = m.profile
    rng = random.Random(27)
    safe = normalized_commands(p.safe_off)  # every stream starts with its outputs off
    start, resets, repeated, base, preamble = 0, 0, 0, 0, safe
    while True:
        after_s = rng.uniform(0.03, 0.12) if resets < 20 else 60.0  # the last run ends by itself
        interrupted = stream_until_reset(m, world, lines, start, after_s)
        segment = world.transcript.commands[base:]
        done = start + max(len(segment) - len(preamble), 0)  # program commands whose motion completed
        assert segment == (preamble + commands[start:done])[:len(segment)], (resets, start)  # in order
        if not interrupted:
            assert done == len(commands)  # the rest ran, exactly once after the last resume
            break
        resets += 1
        m.connect()
        found = m.locate_resume()
        assert found.start <= done, (resets, found, done)  # nothing skipped
        assert done - found.start <= found.repeats, (resets, found, done)  # the stated repeats hold
        assert "none is skipped" in found.summary() and found.as_dict()["skipped"] == 0
        repeated += done - found.start
        base, start = len(world.transcript.commands), found.start
        preamble = safe + ([] if start == 0 else normalized_commands(modal_preamble(
            commands, start, dispense_on=p.dispense_on, dispense_off=p.dispense_off, clearance_z=p.clearance_z))[1:])
    assert resets == 20
    m.disconnect()


def test_the_summary_names_line_basis_and_repeats():
    found = ResumeLocation(41, "planner bound", "why", repeats=3, repeat_moves=2)
    assert found.summary().startswith("resumes at command 42 (by planner bound); commands 42..44 may run")
    assert "2 moves" in found.summary() and found.as_dict()["repeats"] == 3


def test_the_watcher_counts_the_blocks_held_at_the_reset_when_the_mock_was_not_scheduled(make_world):
    """A busy host: the mock's driver thread is not scheduled once 18 blocks are planned (so
    its planner list keeps the blocks that end meanwhile) until every one of them has ended.
    The list's length then still says 18 or more with none held: the watcher does not reset
    then, and resets once the driver runs again and 18 are truly held."""
    m, world = grbl(make_world)
    firmware, frozen, scheduled = world.firmware, [], threading.Event()
    driven = firmware.advance

    def starved(now: float) -> float | None:
        if not frozen and len(firmware.planner) >= 18:
            frozen.append(now)
        return now + 0.002 if frozen and not scheduled.is_set() else driven(now)
    firmware.advance = starved
    failed: list[LinkError] = []

    def stream() -> None:
        try:
            m.stream(short_moves(400))
        except LinkError as exc:
            failed.append(exc)
    streamer = threading.Thread(target=stream)
    streamer.start()
    deadline = time.monotonic() + 10.0
    while not (frozen and time.monotonic() > max(firmware.planner)) and time.monotonic() < deadline:
        time.sleep(0.005)  # until every planned block has ended, unretired
    assert len(firmware.planner) >= 18 and not any(end > time.monotonic() for end in firmware.planner)
    watcher = reset_when_held(world, 18, limit_s=10.0)
    time.sleep(0.05)  # the watcher looks while the list is stale
    scheduled.set()
    watcher.join()
    streamer.join()
    assert failed, "the stream ended without the reset"
    m.connect()
    ran, _, _ = executed_before_the_cut(world, m)
    assert m.interrupted_program.acked_index - ran >= 18, wire_story(m, world)
    m.disconnect()


def test_a_reset_before_the_stream_claims_refuses_it(make_world):
    """A reset that lands between a resume's connect and its stream: the machine has seen
    its link fail, so the stream is refused before a line is sent, and the reconnect
    locates the same resume."""
    m, world = grbl(make_world)
    lines = short_moves(120)
    assert stream_until_reset(m, world, lines, 0, 0.05)
    m.connect()
    found = m.locate_resume()
    sent = len(world.transcript.commands)
    reset_now(world)
    deadline = time.monotonic() + 5.0
    while m.machine_state.state != "error" and time.monotonic() < deadline:
        time.sleep(0.005)
    with pytest.raises(MachineStateError, match="reconnect first"):
        m.stream(lines, start_line=found.start)
    assert len(world.transcript.commands) == sent  # nothing ran
    m.connect()
    assert m.locate_resume().start == found.start
    m.disconnect()


def test_the_reset_lands_in_the_stream_when_the_caller_is_late_to_claim(make_world):
    """A loaded host: the streaming thread claims the machine 0.2 s after the call, well
    after the 0.03 s the reset waits.  The reset still lands in the stream."""
    m, world = grbl(make_world)
    stream = m.stream

    def late_stream(*args, **kwargs):
        time.sleep(0.2)
        return stream(*args, **kwargs)
    m.stream = late_stream
    assert stream_until_reset(m, world, short_moves(120), 0, 0.03)
    assert m.interrupted_program is not None and RESET_TIMES[-1] > 0
    m.connect()
    m.disconnect()
