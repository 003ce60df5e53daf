"""What a mock controller executed around a lost link, and a reset timed inside a stream,
for the resume tests."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from hardware.protocol import normalized_commands

CLAIM_POLL_S = 0.0005


@contextmanager
def reset_in_stream(machine, after_s: float, reset: Callable[[], object]) -> Iterator[None]:  # type: ignore[no-untyped-def]
    """Run ``reset()`` ``after_s`` after ``machine``'s stream inside the block holds the
    machine (its claim), unless the block ended first; on leaving, a reset already under way
    lands before the caller goes on.

    The clock starts at the stream's claim, not at the call: on a loaded host the calling
    thread can lose the processor for longer than ``after_s`` before it claims, and a reset
    that lands first is one the machine rightly refuses to stream after (its link already
    failed), not a reset in the stream."""
    ended = threading.Event()

    def wait_then_reset() -> None:
        while machine.machine_state.current != "printing":
            if ended.wait(CLAIM_POLL_S):
                return
        if not ended.wait(after_s):
            reset()
    resetter = threading.Thread(target=wait_then_reset, daemon=True)
    resetter.start()
    try:
        yield
    finally:
        ended.set()
        resetter.join()


def executed_before_the_cut(world, machine) -> tuple[int, list[str], list[str]]:  # type: ignore[no-untyped-def]
    """(how many of the program's commands the controller executed before the link was cut,
    the ``safe_off`` the program started with, the ``safe_off`` the reconnect sent), read
    from the mock's transcript (reset before the program) right after ``machine.connect()``.

    The transcript is: the program's ``safe_off`` (every program starts with its outputs
    off), the program's executed commands, then the reconnect's ``safe_off`` (a controller
    that kept running through the lost link, a Marlin board that does not reset, gets it
    queued after what it had accepted; one that reset gets it at once; a grbl booting locked
    in Alarm gets none: it refuses G-code and its reset switched its outputs off)."""
    executed = list(world.transcript.commands)
    safe = normalized_commands(machine.profile.safe_off)
    reconnect = safe if machine.outputs is not None and machine.outputs["sent"] else []
    assert executed[:len(safe)] == safe, executed[:3]
    assert executed[len(executed) - len(reconnect):] == reconnect or not reconnect, executed[-3:]
    return len(executed) - len(safe) - len(reconnect), safe, reconnect
