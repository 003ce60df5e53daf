"""What a mock controller executed around a lost link, for the resume tests."""

from __future__ import annotations

from hardware.protocol import normalized_commands


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
