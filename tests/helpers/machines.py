"""What a mock controller executed around a lost link, for the resume tests."""

from __future__ import annotations

from hardware.protocol import normalized_commands


def executed_before_the_cut(world, machine, kept_running: bool) -> tuple[int, list[str]]:  # type: ignore[no-untyped-def]
    """(how many commands the controller executed before the link was cut, the ``safe_off``
    commands it executed on the reconnect), read from the mock's transcript after
    ``machine.connect()``.  A controller that kept running through the lost link (a Marlin
    board that does not reset) gets the profile's ``safe_off`` queued after what it had
    accepted: the transcript must end with exactly those."""
    executed = list(world.transcript.commands)
    safe = normalized_commands(machine.profile.safe_off) if kept_running else []
    assert executed[len(executed) - len(safe):] == safe, executed[-3:]
    return len(executed) - len(safe), safe
